"""C sources of the native FMI 2.0 Co-Simulation FMU (built by `fitter.fmu.native`)."""
