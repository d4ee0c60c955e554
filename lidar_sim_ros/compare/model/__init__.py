"""compare, the model on the measured rays: the prediction on each ray, the likelihood with each material profiled, the fits, the neighbourhoods, the unknown point times."""
