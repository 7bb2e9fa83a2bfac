/*
 * Shared FMI 2.0 Co-Simulation framework of the native semilinear Duhem FMUs.
 *
 * fmi2_framework.c implements every fmi2* function on top of the model hooks
 * of model_interface.h (the same hooks fmi3_framework.c uses for FMI 3.0).
 *
 * Building the binary of an FMU from its sources/ by hand (any C99 compiler;
 * this is what fitter.native_fmu runs at export time):
 *   cc -O2 -fPIC -shared -fvisibility=hidden -I sources \
 *      sources/fmi2_framework.c sources/duhem_model.c -o semilinear_duhem.so -lm
 */
#ifndef FMI2_FRAMEWORK_H
#define FMI2_FRAMEWORK_H

#include "fmi2Functions.h"
#include "model_interface.h"

#endif
