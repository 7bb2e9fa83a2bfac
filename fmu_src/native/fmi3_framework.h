/*
 * Shared FMI 3.0 Co-Simulation framework of the native semilinear Duhem FMUs.
 *
 * fmi3_framework.c implements every fmi3* function on top of the model hooks
 * of model_interface.h, the same hooks and the same model file as the FMI 2.0
 * framework (fmi2_framework.c): Co-Simulation without event mode, early
 * return, intermediate update or clocks; Model Exchange and Scheduled
 * Execution are refused.
 *
 * Building the binary of an FMU from its sources/ by hand (any C99 compiler;
 * this is what fitter.fmu.native runs at export time; sources/buildDescription.xml
 * says the same for importers):
 *   cc -O2 -fPIC -shared -fvisibility=hidden -I sources \
 *      sources/fmi3_framework.c sources/duhem_model.c -o semilinear_duhem.so -lm
 */
#ifndef FMI3_FRAMEWORK_H
#define FMI3_FRAMEWORK_H

#include "fmi3Functions.h"
#include "model_interface.h"

#endif
