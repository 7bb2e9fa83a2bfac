/*
 * Types of the generated model data (model_data.h) of a native semilinear
 * Duhem FMU.  model_data.h is written by fitter.native_fmu and holds numbers
 * and tables only:
 *   DUHEM_GUID, DUHEM_KIND, DUHEM_ORDER, DUHEM_RATE_NODES (rate-dependent),
 *   DUHEM_N_PARAMETERS and duhem_parameters[]: parameter start values in the
 *     layout of duhem_model.c (the model's PARAMS in order, row-major; then
 *     g_v, g_g; then the effect parameters),
 *   DUHEM_EFFECT_*: the index in duhem_parameters of each effect parameter,
 *     -1 when the model has not that effect,
 *   DUHEM_INPUT_START, duhem_variables[] (value reference -> variable) and
 *     duhem_strings[].
 */
#ifndef DUHEM_MODEL_H
#define DUHEM_MODEL_H

#include "fmi2TypesPlatform.h"

#define DUHEM_RATE_INDEPENDENT 1
#define DUHEM_RATE_DEPENDENT 2

/* What a value reference stands for. */
typedef enum {
    VAR_INPUT,      /* Real u: the input */
    VAR_OUTPUT,     /* Real y: the (measured) output */
    VAR_PARAMETER,  /* Real parameter (variability fixed): par[index] */
    VAR_INTEGER,    /* Integer constant (structural): the value is index */
    VAR_STRING      /* String constant (structural): duhem_strings[index] */
} VariableRole;

/* Allowed values of a parameter. */
typedef enum { ANY_FINITE, NONNEGATIVE, POSITIVE } Constraint;

typedef struct {
    const char *name;
    fmi2ValueReference vr;
    char type;      /* 'r' Real, 'i' Integer, 's' String */
    VariableRole role;
    int index;
    Constraint constraint;
} DuhemVariable;

#endif
