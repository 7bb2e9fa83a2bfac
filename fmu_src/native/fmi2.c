/* The framework (cosimulation.c) for FMI 2.0: the file an FMI 2.0 FMU compiles and lists in its
 * <SourceFiles>, which cannot declare the preprocessor definition that selects the version. */
#define FMI_VERSION 2
#include "cosimulation.c"
