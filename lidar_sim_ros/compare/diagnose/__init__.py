"""compare, the diagnosis: what the residual depends on, the candidates and the decision, the reference pose, the separation plan of a tie, the stamp place, sunlight."""
