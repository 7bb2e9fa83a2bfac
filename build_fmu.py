"""FMU generator: a saved model JSON in, an FMI 2.0 Co-Simulation FMU out."""
