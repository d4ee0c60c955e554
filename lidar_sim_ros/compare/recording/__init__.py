"""compare, the recording in: the bag (or pcap) read into measured rays, the point fields, the intensity as power, the shots fired."""
