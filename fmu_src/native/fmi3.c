/* The framework (cosimulation.c) for FMI 3.0: the file an FMI 3.0 FMU compiles and lists in its
 * buildDescription.xml, so that an importer compiles sources/ with no extra flags. */
#define FMI_VERSION 3
#include "cosimulation.c"
