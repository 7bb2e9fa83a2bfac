/*
 * Types of the generated model data (model_data.h) of a native semilinear
 * Duhem FMU.  model_data.h is written by fitter.fmu.native and holds numbers
 * and tables only:
 *   DUHEM_GUID, DUHEM_KIND, DUHEM_ORDER, DUHEM_RATE_NODES (rate-dependent),
 *   DUHEM_N_PARAMETERS and duhem_parameters[]: parameter start values in the
 *     layout of duhem_model.c (the model's PARAMS in order, row-major; then
 *     g_v, g_g; then the effect parameters, each effect's in the order of its
 *     fitter.core.effects.EffectSpec.parameters),
 *   DUHEM_EFFECTS(X): every effect of fitter.core.effects.REGISTRY that the C
 *     implements (EffectSpec.native), in chain order, as
 *     X(name, stage, present, index, offset): its EffectStage, whether the
 *     model has it (0/1), the index in duhem_parameters of its first
 *     parameter and the offset of its state in the chain state (0 when
 *     absent); duhem_model.c calls effect_<name> for each present one,
 *   DUHEM_EFFECT_STATES: the size of the chain state (sum of the present
 *     effects' EffectSpec.state),
 *   DUHEM_EFFECT_START: the index in duhem_parameters of the effects' stored
 *     start (fitter.core.effects.Effect.start: the chain state at the start
 *     time, DUHEM_EFFECT_STATES parameters in the chain state's layout), or
 *     -1 when the chain starts afresh,
 *   DUHEM_INPUT_START, duhem_variables[] (value reference -> variable, with
 *     the allowed range of each parameter, from EffectSpec.parameters; the
 *     last is the independent variable time, which only FMI 3.0 declares) and
 *     duhem_strings[].
 */
#ifndef DUHEM_MODEL_H
#define DUHEM_MODEL_H

#include <math.h>
#include <stddef.h>

#define DUHEM_RATE_INDEPENDENT 1
#define DUHEM_RATE_DEPENDENT 2

/* What a value reference stands for. */
typedef enum {
    VAR_INPUT,      /* Real u: the input */
    VAR_OUTPUT,     /* Real y: the (measured) output */
    VAR_PARAMETER,  /* Real parameter (variability fixed): par[index] */
    VAR_INTEGER,    /* Integer constant (structural): the value is index */
    VAR_STRING,     /* String constant (structural): duhem_strings[index] */
    VAR_TIME        /* Real time: the independent variable (declared by FMI 3.0) */
} VariableRole;

/* Allowed values of a Real variable: finite, lower <= value <= upper, lower < value when strict. */
typedef struct {
    double lower, upper;
    int strict;
    const char *rule;  /* why a value out of range is refused; NULL for ANY_FINITE */
} Range;

#define ANY_FINITE {-HUGE_VAL, HUGE_VAL, 0, NULL}

/* The chain stage an effect acts in (fitter.core.effects.STAGES). */
typedef enum {
    STAGE_INPUT,   /* the base model's input w */
    STAGE_RATE,    /* the coefficients r, S of the flow on the interval */
    STAGE_OUTPUT   /* the output y */
} EffectStage;

typedef struct {
    const char *name;
    unsigned int vr;
    char type;      /* 'r' Real, 'i' Integer, 's' String */
    VariableRole role;
    int index;
    Range range;       /* Real parameters: allowed values */
} DuhemVariable;

#endif
