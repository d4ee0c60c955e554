"""compare, the verdict and the report: the words, summary lines, report.html and its opening, the history of runs."""
