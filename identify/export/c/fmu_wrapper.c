/* fmu_wrapper.c: an FMI 2.0 co-simulation unit around msma_gpi.c's step functions.
 * Written by `python -m identify export` (msma-gpi); fmu_variables.h (generated) says which unit
 * this is (FMU_KIND 0: the model, current -> displacement; 1: the compensator, target -> current),
 * its GUID and its variables.
 *
 * Time: one model sample per communication step. fmi2DoStep(t, h) takes the sample at t (the
 * communication point) with the input set for it; the step size is the model's sample time, so
 * the steps may vary. Outputs read after a step hold that sample's value until the next step;
 * outputs read after an input is set (and before the step) are the coming sample's, computed
 * from the committed state without advancing it (direct feedthrough): the step then commits
 * exactly that sample. The state needs no allocation after fmi2Instantiate.
 */
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "fmi2_declarations.h"
#include "msma_gpi.h"

#include "fmu_variables.h"

#define FMU_INSTANTIATED 0
#define FMU_INITIALIZATION 1
#define FMU_STEPPING 2
#define FMU_TERMINATED 3

#if FMU_KIND == 0
typedef msma_forward engine;
#else
typedef msma_inverse engine;
#endif

typedef struct {
    const fmi2CallbackFunctions *functions;
    char name[128];
    int mode;
    msma_params params;
    double settings[3]; /* the compensator's current_min, current_max, output_scale */
    int creep_stale;    /* a creep parameter or the horizon was set: its modes are computed again */
    engine committed, preview;
    int ready;          /* committed is initialised from the parameters */
    int preview_valid;  /* preview holds the sample at preview_time with preview_input */
    double preview_time, preview_input;
    double time;        /* the next sample's time */
    double input;       /* the input set for it */
    int fresh;          /* an input was set since the last step */
    double output[2];   /* the committed sample's outputs (see FMU_OUTPUTS) */
    int status;
    double preview_output[2];
    int preview_status;
} instance;

static void say(instance *c, fmi2Status status, const char *category, const char *message) {
    if (c && c->functions && c->functions->logger) {
        c->functions->logger(c->functions->componentEnvironment, c->name, status, category, message);
    }
}

static fmi2Status fail(instance *c, const char *message) {
    say(c, fmi2Error, "logStatusError", message);
    return fmi2Error;
}

static double *parameter(instance *c, size_t index) {
    const fmu_parameter *p = &FMU_PARAMETERS[index];
    return p->in_settings ? &c->settings[p->offset] : (double *)((char *)&c->params + p->offset);
}

static long parameter_index(fmi2ValueReference vr) {
    size_t q;
    for (q = 0; q < FMU_N_PARAMETERS; q++) {
        if (FMU_PARAMETERS[q].vr == vr) return (long)q;
    }
    return -1;
}

static void defaults(instance *c) {
    msma_default_params(&c->params);
    c->settings[0] = FMU_CURRENT_MIN;
    c->settings[1] = FMU_CURRENT_MAX;
    c->settings[2] = FMU_OUTPUT_SCALE;
    c->creep_stale = 0;
    memset(&c->committed, 0, sizeof c->committed);
    c->ready = 0;
    c->preview_valid = 0;
    c->fresh = 0;
    c->input = FMU_INPUT_START;
    c->output[0] = c->output[1] = 0.0;
    c->status = 0;
}

/* Initialise the engine from the parameters (once, before the first sample). */
static fmi2Status ready(instance *c) {
    int code;
    if (c->ready) return fmi2OK;
    if (c->creep_stale) msma_creep_constants(&c->params);
#if FMU_KIND == 0
    code = msma_forward_init(&c->committed, &c->params);
#else
    code = msma_inverse_init(&c->committed, &c->params, c->settings[0], c->settings[1], c->settings[2]);
#endif
    if (code == MSMA_BAD_RANGE) return fail(c, "the current range must be current_min < current_max, finite");
    if (code != MSMA_OK) return fail(c, "the model's parameters are not in its domain (msma init refused them)");
    c->ready = 1;
    return fmi2OK;
}

/* The sample at time t with input u into preview (the committed state untouched). */
static fmi2Status compute(instance *c, double t, double u) {
    fmi2Status status = ready(c);
    if (status != fmi2OK) return status;
    if (c->preview_valid && c->preview_time == t && c->preview_input == u) return fmi2OK;
    if (c->committed.k > 0 && !(t > c->committed.t_prev)) {
        return fail(c, "the sample times must increase (a communication point at or before the last sample)");
    }
    c->preview = c->committed;
#if FMU_KIND == 0
    c->preview_output[0] = msma_forward_step(&c->preview, t, u);
    c->preview_status = 0;
#else
    c->preview_output[0] = msma_inverse_step(&c->preview, t, u, &c->preview_status);
    c->preview_output[1] = c->preview.y;
#endif
    c->preview_valid = 1;
    c->preview_time = t;
    c->preview_input = u;
    return fmi2OK;
}

FMI2_EXPORT const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
FMI2_EXPORT const char *fmi2GetVersion(void) { return fmi2Version; }

FMI2_EXPORT fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String categories[]) {
    (void)c, (void)on, (void)n, (void)categories;
    return fmi2OK;
}

FMI2_EXPORT fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String location,
                                          const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                                          fmi2Boolean logging) {
    instance *c;
    (void)location, (void)visible, (void)logging;
    if (!functions || !functions->allocateMemory || !functions->freeMemory) return NULL;
    if (type != fmi2CoSimulation) {
        if (functions->logger) {
            functions->logger(functions->componentEnvironment, name ? name : "", fmi2Error, "logStatusError",
                              "this unit is for co-simulation only");
        }
        return NULL;
    }
    if (!guid || strcmp(guid, FMU_GUID) != 0) {
        if (functions->logger) {
            functions->logger(functions->componentEnvironment, name ? name : "", fmi2Error, "logStatusError",
                              "the GUID is not this unit's (modelDescription.xml and binary differ)");
        }
        return NULL;
    }
    c = (instance *)functions->allocateMemory(1, sizeof(instance));
    if (!c) return NULL;
    memset(c, 0, sizeof *c);
    c->functions = functions;
    strncpy(c->name, name ? name : FMU_MODEL_IDENTIFIER, sizeof c->name - 1);
    c->mode = FMU_INSTANTIATED;
    defaults(c);
    return c;
}

FMI2_EXPORT void fmi2FreeInstance(fmi2Component component) {
    instance *c = (instance *)component;
    if (c) c->functions->freeMemory(c);
}

FMI2_EXPORT fmi2Status fmi2SetupExperiment(fmi2Component component, fmi2Boolean tolerance_defined, fmi2Real tolerance,
                                           fmi2Real start, fmi2Boolean stop_defined, fmi2Real stop) {
    instance *c = (instance *)component;
    (void)tolerance_defined, (void)tolerance, (void)stop_defined, (void)stop;
    if (!c || c->mode != FMU_INSTANTIATED) return fail(c, "fmi2SetupExperiment: only after fmi2Instantiate");
    c->time = start;
    return fmi2OK;
}

FMI2_EXPORT fmi2Status fmi2EnterInitializationMode(fmi2Component component) {
    instance *c = (instance *)component;
    if (!c || c->mode != FMU_INSTANTIATED) return fail(c, "fmi2EnterInitializationMode: only after instantiation");
    c->mode = FMU_INITIALIZATION;
    return fmi2OK;
}

FMI2_EXPORT fmi2Status fmi2ExitInitializationMode(fmi2Component component) {
    instance *c = (instance *)component;
    if (!c || c->mode != FMU_INITIALIZATION) return fail(c, "fmi2ExitInitializationMode: not in initialization");
    c->mode = FMU_STEPPING;
    return ready(c);
}

FMI2_EXPORT fmi2Status fmi2Terminate(fmi2Component component) {
    instance *c = (instance *)component;
    if (!c) return fmi2Error;
    c->mode = FMU_TERMINATED;
    return fmi2OK;
}

FMI2_EXPORT fmi2Status fmi2Reset(fmi2Component component) {
    instance *c = (instance *)component;
    if (!c) return fmi2Error;
    c->mode = FMU_INSTANTIATED;
    c->time = 0.0;
    defaults(c);
    return fmi2OK;
}

FMI2_EXPORT fmi2Status fmi2GetReal(fmi2Component component, const fmi2ValueReference vr[], size_t n,
                                   fmi2Real value[]) {
    instance *c = (instance *)component;
    size_t q;
    if (!c) return fmi2Error;
    for (q = 0; q < n; q++) {
        long index;
        if (vr[q] == FMU_VR_INPUT) {
            value[q] = c->input;
        } else if (vr[q] == FMU_VR_OUTPUT || vr[q] == FMU_VR_MODEL_OUTPUT) {
            int which = vr[q] == FMU_VR_OUTPUT ? 0 : 1;
            if (c->fresh || c->committed.k == 0) {
                fmi2Status status = compute(c, c->time, c->input);
                if (status != fmi2OK) return status;
                value[q] = c->preview_output[which];
            } else {
                value[q] = c->output[which];
            }
        } else if ((index = parameter_index(vr[q])) >= 0) {
            value[q] = *parameter(c, (size_t)index);
        } else {
            return fail(c, "fmi2GetReal: unknown value reference");
        }
    }
    return fmi2OK;
}

FMI2_EXPORT fmi2Status fmi2SetReal(fmi2Component component, const fmi2ValueReference vr[], size_t n,
                                   const fmi2Real value[]) {
    instance *c = (instance *)component;
    size_t q;
    if (!c) return fmi2Error;
    for (q = 0; q < n; q++) {
        long index;
        if (vr[q] == FMU_VR_INPUT) {
            c->input = value[q];
            c->fresh = 1;
        } else if ((index = parameter_index(vr[q])) >= 0) {
            if (c->mode != FMU_INSTANTIATED && c->mode != FMU_INITIALIZATION) {
                return fail(c, "fmi2SetReal: a parameter is fixed after initialization");
            }
            *parameter(c, (size_t)index) = value[q];
            if (FMU_PARAMETERS[index].creep) c->creep_stale = 1;
            c->ready = 0;
            c->preview_valid = 0;
        } else {
            return fail(c, "fmi2SetReal: not an input or a parameter");
        }
    }
    return fmi2OK;
}

FMI2_EXPORT fmi2Status fmi2GetInteger(fmi2Component component, const fmi2ValueReference vr[], size_t n,
                                      fmi2Integer value[]) {
    instance *c = (instance *)component;
    size_t q;
    if (!c) return fmi2Error;
    for (q = 0; q < n; q++) {
        if (FMU_KIND == 1 && vr[q] == FMU_VR_STATUS) {
            if (c->fresh || c->committed.k == 0) {
                fmi2Status status = compute(c, c->time, c->input);
                if (status != fmi2OK) return status;
                value[q] = c->preview_status;
            } else {
                value[q] = c->status;
            }
        } else {
            return fail(c, "fmi2GetInteger: unknown value reference");
        }
    }
    return fmi2OK;
}

FMI2_EXPORT fmi2Status fmi2SetInteger(fmi2Component component, const fmi2ValueReference vr[], size_t n,
                                      const fmi2Integer value[]) {
    (void)vr, (void)value;
    return n == 0 ? fmi2OK : fail((instance *)component, "fmi2SetInteger: this unit has no Integer to set");
}

FMI2_EXPORT fmi2Status fmi2GetBoolean(fmi2Component component, const fmi2ValueReference vr[], size_t n,
                                      fmi2Boolean value[]) {
    (void)vr, (void)value;
    return n == 0 ? fmi2OK : fail((instance *)component, "fmi2GetBoolean: this unit has no Boolean");
}

FMI2_EXPORT fmi2Status fmi2SetBoolean(fmi2Component component, const fmi2ValueReference vr[], size_t n,
                                      const fmi2Boolean value[]) {
    (void)vr, (void)value;
    return n == 0 ? fmi2OK : fail((instance *)component, "fmi2SetBoolean: this unit has no Boolean");
}

FMI2_EXPORT fmi2Status fmi2GetString(fmi2Component component, const fmi2ValueReference vr[], size_t n,
                                     fmi2String value[]) {
    (void)vr, (void)value;
    return n == 0 ? fmi2OK : fail((instance *)component, "fmi2GetString: this unit has no String");
}

FMI2_EXPORT fmi2Status fmi2SetString(fmi2Component component, const fmi2ValueReference vr[], size_t n,
                                     const fmi2String value[]) {
    (void)vr, (void)value;
    return n == 0 ? fmi2OK : fail((instance *)component, "fmi2SetString: this unit has no String");
}

FMI2_EXPORT fmi2Status fmi2GetFMUstate(fmi2Component component, fmi2FMUstate *state) {
    (void)state;
    return fail((instance *)component, "fmi2GetFMUstate: not supported (canGetAndSetFMUstate is false)");
}

FMI2_EXPORT fmi2Status fmi2SetFMUstate(fmi2Component component, fmi2FMUstate state) {
    (void)state;
    return fail((instance *)component, "fmi2SetFMUstate: not supported (canGetAndSetFMUstate is false)");
}

FMI2_EXPORT fmi2Status fmi2FreeFMUstate(fmi2Component component, fmi2FMUstate *state) {
    (void)state;
    return fail((instance *)component, "fmi2FreeFMUstate: not supported (canGetAndSetFMUstate is false)");
}

FMI2_EXPORT fmi2Status fmi2SerializedFMUstateSize(fmi2Component component, fmi2FMUstate state, size_t *size) {
    (void)state, (void)size;
    return fail((instance *)component, "fmi2SerializedFMUstateSize: not supported");
}

FMI2_EXPORT fmi2Status fmi2SerializeFMUstate(fmi2Component component, fmi2FMUstate state, fmi2Byte bytes[],
                                             size_t size) {
    (void)state, (void)bytes, (void)size;
    return fail((instance *)component, "fmi2SerializeFMUstate: not supported");
}

FMI2_EXPORT fmi2Status fmi2DeSerializeFMUstate(fmi2Component component, const fmi2Byte bytes[], size_t size,
                                               fmi2FMUstate *state) {
    (void)bytes, (void)size, (void)state;
    return fail((instance *)component, "fmi2DeSerializeFMUstate: not supported");
}

FMI2_EXPORT fmi2Status fmi2GetDirectionalDerivative(fmi2Component component, const fmi2ValueReference unknown[],
                                                    size_t n_unknown, const fmi2ValueReference known[],
                                                    size_t n_known, const fmi2Real seed[], fmi2Real sensitivity[]) {
    (void)unknown, (void)n_unknown, (void)known, (void)n_known, (void)seed, (void)sensitivity;
    return fail((instance *)component, "fmi2GetDirectionalDerivative: not provided");
}

FMI2_EXPORT fmi2Status fmi2SetRealInputDerivatives(fmi2Component component, const fmi2ValueReference vr[], size_t n,
                                                   const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr, (void)order, (void)value;
    return n == 0 ? fmi2OK : fail((instance *)component, "fmi2SetRealInputDerivatives: inputs are sampled");
}

FMI2_EXPORT fmi2Status fmi2GetRealOutputDerivatives(fmi2Component component, const fmi2ValueReference vr[], size_t n,
                                                    const fmi2Integer order[], fmi2Real value[]) {
    (void)vr, (void)order, (void)value;
    return n == 0 ? fmi2OK : fail((instance *)component, "fmi2GetRealOutputDerivatives: not provided");
}

FMI2_EXPORT fmi2Status fmi2DoStep(fmi2Component component, fmi2Real t, fmi2Real h, fmi2Boolean no_prior) {
    instance *c = (instance *)component;
    fmi2Status status;
    (void)no_prior;
    if (!c || c->mode != FMU_STEPPING) return fail(c, "fmi2DoStep: only after fmi2ExitInitializationMode");
    if (!(h > 0.0)) return fail(c, "fmi2DoStep: the communication step must be > 0 (it is the sample time)");
    status = compute(c, t, c->input);
    if (status != fmi2OK) return status;
    c->committed = c->preview; /* the sample at t, committed */
    c->output[0] = c->preview_output[0];
    c->output[1] = c->preview_output[1];
    c->status = c->preview_status;
    c->preview_valid = 0;
    c->fresh = 0;
    c->time = t + h;
    return fmi2OK;
}

FMI2_EXPORT fmi2Status fmi2CancelStep(fmi2Component component) {
    return fail((instance *)component, "fmi2CancelStep: steps are not asynchronous");
}

FMI2_EXPORT fmi2Status fmi2GetStatus(fmi2Component component, const fmi2StatusKind kind, fmi2Status *value) {
    (void)kind, (void)value;
    return fail((instance *)component, "fmi2GetStatus: steps are not asynchronous");
}

FMI2_EXPORT fmi2Status fmi2GetRealStatus(fmi2Component component, const fmi2StatusKind kind, fmi2Real *value) {
    instance *c = (instance *)component;
    if (c && kind == fmi2LastSuccessfulTime) {
        *value = c->time;
        return fmi2OK;
    }
    return fail(c, "fmi2GetRealStatus: only fmi2LastSuccessfulTime");
}

FMI2_EXPORT fmi2Status fmi2GetIntegerStatus(fmi2Component component, const fmi2StatusKind kind, fmi2Integer *value) {
    (void)kind, (void)value;
    return fail((instance *)component, "fmi2GetIntegerStatus: steps are not asynchronous");
}

FMI2_EXPORT fmi2Status fmi2GetBooleanStatus(fmi2Component component, const fmi2StatusKind kind, fmi2Boolean *value) {
    instance *c = (instance *)component;
    if (c && kind == fmi2Terminated) {
        *value = fmi2False;
        return fmi2OK;
    }
    return fail(c, "fmi2GetBooleanStatus: only fmi2Terminated");
}

FMI2_EXPORT fmi2Status fmi2GetStringStatus(fmi2Component component, const fmi2StatusKind kind, fmi2String *value) {
    (void)kind, (void)value;
    return fail((instance *)component, "fmi2GetStringStatus: steps are not asynchronous");
}
