/*
 * The interface between a model file (duhem_model.c, gain_model.c) and the
 * FMI framework that exposes it: cosimulation.c, compiled for FMI 2.0
 * (fmi2.c) or FMI 3.0 (fmi3.c) Co-Simulation.  One model file serves both
 * versions: it includes no FMI header and uses plain C types only (a value
 * reference is an unsigned int, an Integer an int, a Boolean an int 0/1, a
 * String a const char *); the framework converts each version's types at the
 * call.
 *
 * The framework implements the instance, the call state machine, argument
 * checks, logging, value access dispatch and FMU state get/set/serialize.  It
 * knows nothing about the model: the model file implements the hooks declared
 * below on an opaque, pointer-free block of model data, so that an FMU state
 * is a plain copy of that block.
 *
 * Every hook that can fail returns NULL on success or a static message
 * saying why; a hook that fails changes nothing.
 */
#ifndef MODEL_INTERFACE_H
#define MODEL_INTERFACE_H

#include <stddef.h>

/* The model's data: parameters, anchor, current input and time (no pointers). */
typedef struct ModelData ModelData;

/* The phase a setter is called in: before the first step, or while stepping. */
typedef enum { PHASE_CONFIGURE = 0, PHASE_STEP = 1 } ModelPhase;

size_t model_size(void);
/* The FMI 2 GUID / FMI 3 instantiationToken the instance must be created with. */
const char *model_guid(void);

/* Start values of all variables, at time t0. */
void model_defaults(ModelData *m, double t0);
/* Set the start time (before the first step). */
const char *model_set_start_time(ModelData *m, double t0);
double model_time(const ModelData *m);
/* Check that a block of model data (e.g. deserialized) is consistent; derived data is rebuilt. */
const char *model_validate(ModelData *m);
/* End of initialization: check the parameters as a whole. */
const char *model_exit_initialization(ModelData *m);

/* Name of the variable of this type ('r', 'i', 'b', 's') and value reference, for messages. */
const char *model_variable_name(char type, unsigned int vr);

const char *model_get_real(ModelData *m, unsigned int vr, double *value);
const char *model_get_integer(const ModelData *m, unsigned int vr, int *value);
const char *model_get_boolean(const ModelData *m, unsigned int vr, int *value);
const char *model_get_string(const ModelData *m, unsigned int vr, const char **value);
/* Whether vr may be set to value in this phase (NULL: yes); then model_set_real applies it. */
const char *model_check_set_real(const ModelData *m, unsigned int vr, double value,
                                 ModelPhase phase);
void model_set_real(ModelData *m, unsigned int vr, double value, ModelPhase phase);
/* Integer, Boolean and String variables are structural constants: only their own value is accepted. */
const char *model_check_set_integer(const ModelData *m, unsigned int vr, int value);
const char *model_check_set_boolean(const ModelData *m, unsigned int vr, int value);
const char *model_check_set_string(const ModelData *m, unsigned int vr, const char *value);
/* Commit the current point and advance the time by h > 0. */
const char *model_do_step(ModelData *m, double h);
/* An input derivative of the given order (FMI 2 fmi2SetRealInputDerivatives; NULL: accepted). */
const char *model_set_input_derivative(ModelData *m, unsigned int vr, int order, double value);

#endif
