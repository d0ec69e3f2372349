/* tendonkit model FMU: the FMI 2.0 and FMI 3.0 co-simulation interfaces of the runtime.
 *
 * One binary exports both APIs; an FMU of either version carries it under its modelIdentifier.
 * Variables (value references): the model's inputs 0..nu-1, its outputs (with q3..q6 and the
 * end effector when the kinematics is on) nu..nu+nout-1, then the four ratio parameters, then
 * (FMI 3.0) the independent variable time.  The step is fixed at the model's sample time.
 *
 * Bad calls never crash the importer: a non-finite input, an unknown value reference, a wrong
 * step size or a model that diverges is logged at error level and answered with an error
 * status; the state is left as it was.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "fmi3Functions.h"
#include "tendonkit_runtime.h"

#define MODEL_FILE "model.tkm"

#if defined(_WIN32) && defined(TK_NO_CRT)
/* Built without a C runtime (msvcrt.dll imported directly): the DLL entry point is ours. */
int __stdcall DllMainCRTStartup(void *module, unsigned long reason, void *reserved) {
    (void)module;
    (void)reason;
    (void)reserved;
    return 1;
}
#endif
#define STATE_MAGIC 911.5

enum { MODE_INSTANTIATED, MODE_INIT, MODE_STEP, MODE_TERMINATED, MODE_ERROR };
enum { ST_OK = 0, ST_WARNING = 1, ST_DISCARD = 2, ST_ERROR = 3, ST_FATAL = 4 };

typedef struct {
    tk_model m;
    int fmi;
    char name[256];
    int logging;
    fmi2CallbackFunctions cb2;
    fmi3LogMessageCallback log3;
    fmi3InstanceEnvironment env3;
    double t;
    int mode;
    int valid;
    double *out;
} instance;

static void logmsg(instance *c, int status, const char *fmt, ...) {
    char buf[1024];
    char *p;
    va_list ap;
    if (status == ST_OK && !c->logging) return;
    va_start(ap, fmt);
    TK_VSNPRINTF(buf, sizeof(buf), fmt, ap);
    buf[sizeof(buf) - 1] = 0;
    va_end(ap);
    for (p = buf; *p; p++)
        if (*p == '%') *p = '#'; /* an FMI 2.0 logger may treat the message as a format */
    if (c->fmi == 2 && c->cb2.logger)
        c->cb2.logger(c->cb2.componentEnvironment, c->name, (fmi2Status)status,
                      status >= ST_ERROR ? "logStatusError" : "logAll", buf);
    else if (c->fmi == 3 && c->log3)
        c->log3(c->env3, (fmi3Status)status, status >= ST_ERROR ? "logStatusError" : "logAll", buf);
}

/* The resource folder from an FMI 2.0 URI (file:///C:/x%20y/ or file:/x/) or an FMI 3.0 path. */
static int resource_file(const char *location, int uri, char *path, size_t n) {
    char *tmp;
    size_t i = 0, k = 0, cap;
    const char *s = location;
    int bad;
    if (!s) return 1;
    cap = strlen(s) + 1;
    tmp = (char *)malloc(cap);
    if (!tmp) return 1;
    if (uri) {
        if (strncmp(s, "file://", 7) == 0) {
            s += 7;
            if (strncmp(s, "localhost/", 10) == 0) s += 9;
        } else if (strncmp(s, "file:", 5) == 0) {
            s += 5;
        } else {
            free(tmp);
            return 1;
        }
#ifdef _WIN32
        if (s[0] == '/' && s[1] && s[2] == ':') s++; /* /C:/... */
#endif
        while (s[i] && k + 1 < cap) {
            if (s[i] == '%' && s[i + 1] && s[i + 2]) {
                char hex[3] = {s[i + 1], s[i + 2], 0};
                tmp[k++] = (char)strtol(hex, NULL, 16);
                i += 3;
            } else {
                tmp[k++] = s[i++];
            }
        }
        tmp[k] = 0;
    } else {
        memcpy(tmp, s, cap);
    }
    k = strlen(tmp);
    if (k && (tmp[k - 1] == '/' || tmp[k - 1] == '\\')) tmp[--k] = 0;
    bad = k + strlen(MODEL_FILE) + 2 > n;
    if (!bad) TK_SNPRINTF(path, n, "%s/%s", tmp, MODEL_FILE);
    free(tmp);
    return bad;
}

static instance *create(int fmi, const char *name, const char *location, int uri, int logging,
                        const fmi2CallbackFunctions *cb2, fmi3LogMessageCallback log3,
                        fmi3InstanceEnvironment env3) {
    size_t np = (location ? strlen(location) : 0) + 64;
    char *path, *why;
    instance *c = (instance *)calloc(1, sizeof(instance));
    if (!c) return NULL;
    path = (char *)malloc(np);
    why = (char *)malloc(np + 256);
    if (!path || !why) {
        free(path);
        free(why);
        free(c);
        return NULL;
    }
    c->fmi = fmi;
    TK_SNPRINTF(c->name, sizeof(c->name), "%s", name ? name : "tendonkit");
    c->logging = logging;
    if (cb2) c->cb2 = *cb2;
    c->log3 = log3;
    c->env3 = env3;
    if (resource_file(location, uri, path, np)) {
        logmsg(c, ST_ERROR, "cannot find the FMU's resources from the location '%s'",
               location ? location : "(null)");
        free(path);
        free(why);
        free(c);
        return NULL;
    }
    if (tk_load(&c->m, path, why, np + 256)) {
        logmsg(c, ST_ERROR, "%s", why);
        free(path);
        free(why);
        free(c);
        return NULL;
    }
    free(path);
    free(why);
    c->out = (double *)calloc((size_t)c->m.nout + 1, sizeof(double));
    if (!c->out) {
        tk_free(&c->m);
        free(c);
        return NULL;
    }
    c->mode = MODE_INSTANTIATED;
    logmsg(c, ST_OK, "tendonkit model: %d inputs, %d outputs, step %g s", c->m.nu, c->m.nout,
           c->m.dt);
    return c;
}

static void destroy(instance *c) {
    if (!c) return;
    tk_free(&c->m);
    free(c->out);
    free(c);
}

static int n_ratio(const instance *c) { return c->m.kin ? 4 : 0; }
static unsigned vr_time(const instance *c) {
    return (unsigned)(c->m.nu + c->m.nout + n_ratio(c));
}

static const double *outputs(instance *c) {
    if (!c->valid) {
        tk_outputs(&c->m, c->out);
        c->valid = 1;
    }
    return c->out;
}

static int get_real(instance *c, const unsigned *vr, size_t n, double *v) {
    size_t k;
    unsigned nu = (unsigned)c->m.nu, nout = (unsigned)c->m.nout;
    for (k = 0; k < n; k++) {
        unsigned r = vr[k];
        if (r < nu) v[k] = c->m.S[c->m.s_u + r];
        else if (r < nu + nout) v[k] = outputs(c)[r - nu];
        else if (r < nu + nout + (unsigned)n_ratio(c)) v[k] = c->m.S[c->m.s_ratio + (r - nu - nout)];
        else if (c->fmi == 3 && r == vr_time(c)) v[k] = c->t;
        else {
            logmsg(c, ST_ERROR, "get: no variable has value reference %u", r);
            return ST_ERROR;
        }
    }
    return ST_OK;
}

static int set_real(instance *c, const unsigned *vr, size_t n, const double *v) {
    size_t k;
    unsigned nu = (unsigned)c->m.nu, nout = (unsigned)c->m.nout;
    int status = ST_OK;
    for (k = 0; k < n; k++) {
        unsigned r = vr[k];
        if (r < nu || (r >= nu + nout && r < nu + nout + (unsigned)n_ratio(c))) {
            if (!TK_FINITE(v[k])) {
                logmsg(c, ST_ERROR,
                       "%s with value reference %u set to %g refused: values must be finite; "
                       "it keeps %g",
                       r < nu ? "input" : "parameter", r, v[k],
                       c->m.S[(r < nu ? c->m.s_u + r : c->m.s_ratio + (r - nu - nout))]);
                status = ST_ERROR;
                continue;
            }
            c->m.S[r < nu ? c->m.s_u + r : c->m.s_ratio + (r - nu - nout)] = v[k];
            c->valid = 0;
        } else if (r < nu + nout) {
            logmsg(c, ST_ERROR, "set: value reference %u is an output and cannot be set", r);
            status = ST_ERROR;
        } else {
            logmsg(c, ST_ERROR, "set: no settable variable has value reference %u", r);
            status = ST_ERROR;
        }
    }
    return status;
}

static int do_step(instance *c, double t, double h) {
    double dt = c->m.dt;
    if (c->mode != MODE_STEP) {
        logmsg(c, ST_ERROR, "doStep called before the initialization mode was left");
        return ST_ERROR;
    }
    if (!(fabs(h - dt) <= 1e-9 * (dt > 1.0 ? dt : 1.0))) {
        logmsg(c, ST_ERROR,
               "communication step %.17g s refused: this model FMU steps at exactly its sample "
               "time %.17g s; the state did not change",
               h, dt);
        return ST_ERROR;
    }
    if (c->m.S[TK_DEAD] != 0.0) {
        logmsg(c, ST_ERROR, "the model diverged before t = %g s; its outputs are NaN", t);
        return ST_ERROR;
    }
    tk_advance(&c->m);
    c->valid = 0;
    c->t = t + h;
    if (c->m.S[TK_DEAD] != 0.0) {
        logmsg(c, ST_ERROR,
               "the model diverged in the step from t = %g s (an output or a state is no "
               "longer finite); its outputs are NaN from here on",
               t);
        return ST_ERROR;
    }
    return ST_OK;
}

/* FMU states: [magic, ns, t, S...] */
static double *get_state(instance *c, double *old) {
    double *s = old ? old : (double *)malloc(((size_t)c->m.ns + 3) * sizeof(double));
    if (!s) return NULL;
    s[0] = STATE_MAGIC;
    s[1] = c->m.ns;
    s[2] = c->t;
    memcpy(s + 3, c->m.S, (size_t)c->m.ns * sizeof(double));
    return s;
}

/* Whether s is a state of this model that it can continue from. */
static int state_valid(const instance *c, const double *s) {
    return s && s[0] == STATE_MAGIC && s[1] == c->m.ns && tk_state_ok(&c->m, s + 3);
}

static int set_state(instance *c, const double *s) {
    if (!state_valid(c, s)) {
        logmsg(c, ST_ERROR, "FMU state not restored: it belongs to another model");
        return ST_ERROR;
    }
    c->t = s[2];
    memcpy(c->m.S, s + 3, (size_t)c->m.ns * sizeof(double));
    c->valid = 0;
    return ST_OK;
}

static size_t state_bytes(const instance *c) { return ((size_t)c->m.ns + 3) * sizeof(double); }

static int serialize(instance *c, const double *state, void *bytes, size_t size) {
    if (!state || size < state_bytes(c)) return ST_ERROR;
    memcpy(bytes, state, state_bytes(c));
    return ST_OK;
}

/* A new FMU state from serialised bytes, or an error (logged) if they are not this model's. */
static int deserialize(instance *c, const void *bytes, size_t size, double **state) {
    double *s;
    if (size != state_bytes(c)) {
        logmsg(c, ST_ERROR, "serialized FMU state of %lu bytes refused: this model's has %lu",
               (unsigned long)size, (unsigned long)state_bytes(c));
        return ST_ERROR;
    }
    s = (double *)malloc(size);
    if (!s) return ST_ERROR;
    memcpy(s, bytes, size);
    if (!state_valid(c, s)) {
        free(s);
        logmsg(c, ST_ERROR, "serialized FMU state refused: it belongs to another model");
        return ST_ERROR;
    }
    *state = s;
    return ST_OK;
}

static void reset(instance *c) {
    tk_reset(&c->m);
    c->t = 0.0;
    c->valid = 0;
    c->mode = MODE_INSTANTIATED;
}

static int no_values(instance *c, const char *what, size_t n) {
    if (n == 0) return ST_OK;
    logmsg(c, ST_ERROR, "this FMU has no %s variables", what);
    return ST_ERROR;
}

static int unsupported(instance *c, const char *what) {
    if (c) logmsg(c, ST_ERROR, "%s is not supported by this co-simulation FMU", what);
    return ST_ERROR;
}

/* =============================================================================== FMI 2.0 */

#define C2 ((instance *)c)

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    (void)fmuGUID;
    (void)visible;
    if (fmuType != fmi2CoSimulation) {
        instance tmp;
        memset(&tmp, 0, sizeof(tmp));
        tmp.fmi = 2;
        if (functions) tmp.cb2 = *functions;
        TK_SNPRINTF(tmp.name, sizeof(tmp.name), "%s", instanceName ? instanceName : "tendonkit");
        logmsg(&tmp, ST_ERROR, "this FMU supports co-simulation only");
        return NULL;
    }
    return create(2, instanceName, fmuResourceLocation, 1, loggingOn, functions, NULL, NULL);
}

void fmi2FreeInstance(fmi2Component c) { destroy(C2); }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    (void)nCategories;
    (void)categories;
    if (!c) return fmi2Error;
    C2->logging = loggingOn;
    return fmi2OK;
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined,
                               fmi2Real tolerance, fmi2Real startTime,
                               fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    if (!c) return fmi2Error;
    C2->t = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    if (!c) return fmi2Error;
    C2->mode = MODE_INIT;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    if (!c) return fmi2Error;
    C2->mode = MODE_STEP;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    if (!c) return fmi2Error;
    C2->mode = MODE_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    if (!c) return fmi2Error;
    reset(C2);
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[]) {
    if (!c) return fmi2Error;
    return (fmi2Status)get_real(C2, vr, nvr, value);
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) {
    if (!c) return fmi2Error;
    return (fmi2Status)set_real(C2, vr, nvr, value);
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[]) {
    (void)vr;
    (void)value;
    return c ? (fmi2Status)no_values(C2, "Integer", nvr) : fmi2Error;
}
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean value[]) {
    (void)vr;
    (void)value;
    return c ? (fmi2Status)no_values(C2, "Boolean", nvr) : fmi2Error;
}
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[]) {
    (void)vr;
    (void)value;
    return c ? (fmi2Status)no_values(C2, "String", nvr) : fmi2Error;
}
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    (void)vr;
    (void)value;
    return c ? (fmi2Status)no_values(C2, "Integer", nvr) : fmi2Error;
}
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    (void)vr;
    (void)value;
    return c ? (fmi2Status)no_values(C2, "Boolean", nvr) : fmi2Error;
}
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[]) {
    (void)vr;
    (void)value;
    return c ? (fmi2Status)no_values(C2, "String", nvr) : fmi2Error;
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state) {
    double *s;
    if (!c || !state) return fmi2Error;
    s = get_state(C2, (double *)*state);
    if (!s) return fmi2Error;
    *state = s;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state) {
    if (!c) return fmi2Error;
    return (fmi2Status)set_state(C2, (const double *)state);
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state) {
    (void)c;
    if (state) {
        free(*state);
        *state = NULL;
    }
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate state, size_t *size) {
    (void)state;
    if (!c || !size) return fmi2Error;
    *size = state_bytes(C2);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate state, fmi2Byte bytes[],
                                 size_t size) {
    if (!c) return fmi2Error;
    return (fmi2Status)serialize(C2, (const double *)state, bytes, size);
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t size,
                                   fmi2FMUstate *state) {
    double *s;
    if (!c || !state) return fmi2Error;
    if (deserialize(C2, bytes, size, &s) != ST_OK) return fmi2Error;
    free(*state);
    *state = s;
    return fmi2OK;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown[],
                                        size_t nUnknown, const fmi2ValueReference vKnown[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[]) {
    (void)vUnknown;
    (void)nUnknown;
    (void)vKnown;
    (void)nKnown;
    (void)dvKnown;
    (void)dvUnknown;
    return (fmi2Status)unsupported(C2, "fmi2GetDirectionalDerivative");
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
                                       size_t nvr, const fmi2Integer order[],
                                       const fmi2Real value[]) {
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    return (fmi2Status)unsupported(C2, "fmi2SetRealInputDerivatives");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
                                        size_t nvr, const fmi2Integer order[],
                                        fmi2Real value[]) {
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    return (fmi2Status)unsupported(C2, "fmi2GetRealOutputDerivatives");
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize, fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!c) return fmi2Error;
    return (fmi2Status)do_step(C2, currentCommunicationPoint, communicationStepSize);
}

fmi2Status fmi2CancelStep(fmi2Component c) { return (fmi2Status)unsupported(C2, "fmi2CancelStep"); }

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)s;
    (void)value;
    return (fmi2Status)unsupported(C2, "fmi2GetStatus (steps are synchronous)");
}
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    if (!c) return fmi2Error;
    if (s == fmi2LastSuccessfulTime && value) {
        *value = C2->t;
        return fmi2OK;
    }
    return (fmi2Status)unsupported(C2, "fmi2GetRealStatus of this kind");
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)s;
    (void)value;
    return (fmi2Status)unsupported(C2, "fmi2GetIntegerStatus");
}
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    (void)s;
    (void)value;
    return (fmi2Status)unsupported(C2, "fmi2GetBooleanStatus");
}
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)s;
    (void)value;
    return (fmi2Status)unsupported(C2, "fmi2GetStringStatus");
}

/* =============================================================================== FMI 3.0 */

#define C3 ((instance *)instance_)

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance_, fmi3Boolean loggingOn,
                               size_t nCategories, const fmi3String categories[]) {
    (void)nCategories;
    (void)categories;
    if (!instance_) return fmi3Error;
    C3->logging = loggingOn;
    return fmi3OK;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName,
                                          fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible,
                                          fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    (void)instanceName;
    (void)instantiationToken;
    (void)resourcePath;
    (void)visible;
    (void)loggingOn;
    if (logMessage)
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "this FMU supports co-simulation only");
    return NULL;
}

fmi3Instance fmi3InstantiateCoSimulation(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
    fmi3Boolean earlyReturnAllowed, const fmi3ValueReference requiredIntermediateVariables[],
    size_t nRequiredIntermediateVariables, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3IntermediateUpdateCallback intermediateUpdate) {
    (void)instantiationToken;
    (void)visible;
    (void)eventModeUsed;
    (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables;
    (void)nRequiredIntermediateVariables;
    (void)intermediateUpdate;
    return create(3, instanceName, resourcePath, 0, loggingOn, NULL, logMessage,
                  instanceEnvironment);
}

fmi3Instance fmi3InstantiateScheduledExecution(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
    fmi3LockPreemptionCallback lockPreemption, fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)instanceName;
    (void)instantiationToken;
    (void)resourcePath;
    (void)visible;
    (void)loggingOn;
    (void)clockUpdate;
    (void)lockPreemption;
    (void)unlockPreemption;
    if (logMessage)
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "this FMU supports co-simulation only");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance_) { destroy(C3); }

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance_, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    if (!instance_) return fmi3Error;
    C3->t = startTime;
    C3->mode = MODE_INIT;
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance_) {
    if (!instance_) return fmi3Error;
    C3->mode = MODE_STEP;
    return fmi3OK;
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance_) {
    return (fmi3Status)unsupported(C3, "fmi3EnterEventMode");
}

fmi3Status fmi3Terminate(fmi3Instance instance_) {
    if (!instance_) return fmi3Error;
    C3->mode = MODE_TERMINATED;
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance instance_) {
    if (!instance_) return fmi3Error;
    reset(C3);
    return fmi3OK;
}

fmi3Status fmi3GetFloat64(fmi3Instance instance_, const fmi3ValueReference vr[], size_t nvr,
                          fmi3Float64 values[], size_t nValues) {
    if (!instance_) return fmi3Error;
    if (nValues < nvr) return (fmi3Status)unsupported(C3, "arrays (nValues != nValueReferences)");
    return (fmi3Status)get_real(C3, vr, nvr, values);
}

fmi3Status fmi3SetFloat64(fmi3Instance instance_, const fmi3ValueReference vr[], size_t nvr,
                          const fmi3Float64 values[], size_t nValues) {
    if (!instance_) return fmi3Error;
    if (nValues < nvr) return (fmi3Status)unsupported(C3, "arrays (nValues != nValueReferences)");
    return (fmi3Status)set_real(C3, vr, nvr, values);
}

#define NO_GET(NAME, TYPE, WHAT)                                                              \
    fmi3Status NAME(fmi3Instance instance_, const fmi3ValueReference vr[], size_t nvr,        \
                    TYPE values[], size_t nValues) {                                          \
        (void)vr;                                                                             \
        (void)values;                                                                         \
        (void)nValues;                                                                        \
        return instance_ ? (fmi3Status)no_values(C3, WHAT, nvr) : fmi3Error;                  \
    }
#define NO_SET(NAME, TYPE, WHAT)                                                              \
    fmi3Status NAME(fmi3Instance instance_, const fmi3ValueReference vr[], size_t nvr,        \
                    const TYPE values[], size_t nValues) {                                    \
        (void)vr;                                                                             \
        (void)values;                                                                         \
        (void)nValues;                                                                        \
        return instance_ ? (fmi3Status)no_values(C3, WHAT, nvr) : fmi3Error;                  \
    }

NO_GET(fmi3GetFloat32, fmi3Float32, "Float32")
NO_GET(fmi3GetInt8, fmi3Int8, "Int8")
NO_GET(fmi3GetUInt8, fmi3UInt8, "UInt8")
NO_GET(fmi3GetInt16, fmi3Int16, "Int16")
NO_GET(fmi3GetUInt16, fmi3UInt16, "UInt16")
NO_GET(fmi3GetInt32, fmi3Int32, "Int32")
NO_GET(fmi3GetUInt32, fmi3UInt32, "UInt32")
NO_GET(fmi3GetInt64, fmi3Int64, "Int64")
NO_GET(fmi3GetUInt64, fmi3UInt64, "UInt64")
NO_GET(fmi3GetBoolean, fmi3Boolean, "Boolean")
NO_GET(fmi3GetString, fmi3String, "String")
NO_SET(fmi3SetFloat32, fmi3Float32, "Float32")
NO_SET(fmi3SetInt8, fmi3Int8, "Int8")
NO_SET(fmi3SetUInt8, fmi3UInt8, "UInt8")
NO_SET(fmi3SetInt16, fmi3Int16, "Int16")
NO_SET(fmi3SetUInt16, fmi3UInt16, "UInt16")
NO_SET(fmi3SetInt32, fmi3Int32, "Int32")
NO_SET(fmi3SetUInt32, fmi3UInt32, "UInt32")
NO_SET(fmi3SetInt64, fmi3Int64, "Int64")
NO_SET(fmi3SetUInt64, fmi3UInt64, "UInt64")
NO_SET(fmi3SetBoolean, fmi3Boolean, "Boolean")
NO_SET(fmi3SetString, fmi3String, "String")

fmi3Status fmi3GetBinary(fmi3Instance instance_, const fmi3ValueReference vr[], size_t nvr,
                         size_t valueSizes[], fmi3Binary values[], size_t nValues) {
    (void)vr;
    (void)valueSizes;
    (void)values;
    (void)nValues;
    return instance_ ? (fmi3Status)no_values(C3, "Binary", nvr) : fmi3Error;
}

fmi3Status fmi3SetBinary(fmi3Instance instance_, const fmi3ValueReference vr[], size_t nvr,
                         const size_t valueSizes[], const fmi3Binary values[], size_t nValues) {
    (void)vr;
    (void)valueSizes;
    (void)values;
    (void)nValues;
    return instance_ ? (fmi3Status)no_values(C3, "Binary", nvr) : fmi3Error;
}

fmi3Status fmi3GetClock(fmi3Instance instance_, const fmi3ValueReference vr[], size_t nvr,
                        fmi3Clock values[]) {
    (void)vr;
    (void)values;
    return instance_ ? (fmi3Status)no_values(C3, "Clock", nvr) : fmi3Error;
}

fmi3Status fmi3SetClock(fmi3Instance instance_, const fmi3ValueReference vr[], size_t nvr,
                        const fmi3Clock values[]) {
    (void)vr;
    (void)values;
    return instance_ ? (fmi3Status)no_values(C3, "Clock", nvr) : fmi3Error;
}

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance_,
                                               fmi3ValueReference valueReference,
                                               size_t *nDependencies) {
    (void)valueReference;
    (void)nDependencies;
    return (fmi3Status)unsupported(C3, "fmi3GetNumberOfVariableDependencies");
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance instance_, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[],
                                       fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[],
                                       fmi3DependencyKind dependencyKinds[],
                                       size_t nDependencies) {
    (void)dependent;
    (void)elementIndicesOfDependent;
    (void)independents;
    (void)elementIndicesOfIndependents;
    (void)dependencyKinds;
    (void)nDependencies;
    return (fmi3Status)unsupported(C3, "fmi3GetVariableDependencies");
}

fmi3Status fmi3GetFMUState(fmi3Instance instance_, fmi3FMUState *state) {
    double *s;
    if (!instance_ || !state) return fmi3Error;
    s = get_state(C3, (double *)*state);
    if (!s) return fmi3Error;
    *state = s;
    return fmi3OK;
}

fmi3Status fmi3SetFMUState(fmi3Instance instance_, fmi3FMUState state) {
    if (!instance_) return fmi3Error;
    return (fmi3Status)set_state(C3, (const double *)state);
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance_, fmi3FMUState *state) {
    (void)instance_;
    if (state) {
        free(*state);
        *state = NULL;
    }
    return fmi3OK;
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance_, fmi3FMUState state, size_t *size) {
    (void)state;
    if (!instance_ || !size) return fmi3Error;
    *size = state_bytes(C3);
    return fmi3OK;
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance_, fmi3FMUState state,
                                 fmi3Byte serializedState[], size_t size) {
    if (!instance_) return fmi3Error;
    return (fmi3Status)serialize(C3, (const double *)state, serializedState, size);
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance_, const fmi3Byte serializedState[],
                                   size_t size, fmi3FMUState *state) {
    double *s;
    if (!instance_ || !state) return fmi3Error;
    if (deserialize(C3, serializedState, size, &s) != ST_OK) return fmi3Error;
    *state = s;
    return fmi3OK;
}

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance_, const fmi3ValueReference unknowns[],
                                        size_t nUnknowns, const fmi3ValueReference knowns[],
                                        size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                        fmi3Float64 sensitivity[], size_t nSensitivity) {
    (void)unknowns;
    (void)nUnknowns;
    (void)knowns;
    (void)nKnowns;
    (void)seed;
    (void)nSeed;
    (void)sensitivity;
    (void)nSensitivity;
    return (fmi3Status)unsupported(C3, "fmi3GetDirectionalDerivative");
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance_, const fmi3ValueReference unknowns[],
                                    size_t nUnknowns, const fmi3ValueReference knowns[],
                                    size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                    fmi3Float64 sensitivity[], size_t nSensitivity) {
    (void)unknowns;
    (void)nUnknowns;
    (void)knowns;
    (void)nKnowns;
    (void)seed;
    (void)nSeed;
    (void)sensitivity;
    (void)nSensitivity;
    return (fmi3Status)unsupported(C3, "fmi3GetAdjointDerivative");
}

fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance_) {
    return (fmi3Status)unsupported(C3, "fmi3EnterConfigurationMode (no structural parameters)");
}
fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance_) {
    return (fmi3Status)unsupported(C3, "fmi3ExitConfigurationMode (no structural parameters)");
}

fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance_, const fmi3ValueReference vr[],
                                  size_t nvr, fmi3Float64 intervals[],
                                  fmi3IntervalQualifier qualifiers[]) {
    (void)vr;
    (void)intervals;
    (void)qualifiers;
    return instance_ ? (fmi3Status)no_values(C3, "Clock", nvr) : fmi3Error;
}
fmi3Status fmi3GetIntervalFraction(fmi3Instance instance_, const fmi3ValueReference vr[],
                                   size_t nvr, fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                                   fmi3IntervalQualifier qualifiers[]) {
    (void)vr;
    (void)counters;
    (void)resolutions;
    (void)qualifiers;
    return instance_ ? (fmi3Status)no_values(C3, "Clock", nvr) : fmi3Error;
}
fmi3Status fmi3GetShiftDecimal(fmi3Instance instance_, const fmi3ValueReference vr[],
                               size_t nvr, fmi3Float64 shifts[]) {
    (void)vr;
    (void)shifts;
    return instance_ ? (fmi3Status)no_values(C3, "Clock", nvr) : fmi3Error;
}
fmi3Status fmi3GetShiftFraction(fmi3Instance instance_, const fmi3ValueReference vr[],
                                size_t nvr, fmi3UInt64 counters[], fmi3UInt64 resolutions[]) {
    (void)vr;
    (void)counters;
    (void)resolutions;
    return instance_ ? (fmi3Status)no_values(C3, "Clock", nvr) : fmi3Error;
}
fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance_, const fmi3ValueReference vr[],
                                  size_t nvr, const fmi3Float64 intervals[]) {
    (void)vr;
    (void)intervals;
    return instance_ ? (fmi3Status)no_values(C3, "Clock", nvr) : fmi3Error;
}
fmi3Status fmi3SetIntervalFraction(fmi3Instance instance_, const fmi3ValueReference vr[],
                                   size_t nvr, const fmi3UInt64 counters[],
                                   const fmi3UInt64 resolutions[]) {
    (void)vr;
    (void)counters;
    (void)resolutions;
    return instance_ ? (fmi3Status)no_values(C3, "Clock", nvr) : fmi3Error;
}
fmi3Status fmi3SetShiftDecimal(fmi3Instance instance_, const fmi3ValueReference vr[],
                               size_t nvr, const fmi3Float64 shifts[]) {
    (void)vr;
    (void)shifts;
    return instance_ ? (fmi3Status)no_values(C3, "Clock", nvr) : fmi3Error;
}
fmi3Status fmi3SetShiftFraction(fmi3Instance instance_, const fmi3ValueReference vr[],
                                size_t nvr, const fmi3UInt64 counters[],
                                const fmi3UInt64 resolutions[]) {
    (void)vr;
    (void)counters;
    (void)resolutions;
    return instance_ ? (fmi3Status)no_values(C3, "Clock", nvr) : fmi3Error;
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance_) {
    return (fmi3Status)unsupported(C3, "fmi3EvaluateDiscreteStates");
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance_, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged,
                                    fmi3Boolean *nextEventTimeDefined, fmi3Float64 *nextEventTime) {
    (void)discreteStatesNeedUpdate;
    (void)terminateSimulation;
    (void)nominalsOfContinuousStatesChanged;
    (void)valuesOfContinuousStatesChanged;
    (void)nextEventTimeDefined;
    (void)nextEventTime;
    return (fmi3Status)unsupported(C3, "fmi3UpdateDiscreteStates (no event mode)");
}

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance_) {
    return (fmi3Status)unsupported(C3, "model exchange");
}
fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance_,
                                       fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode,
                                       fmi3Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint;
    (void)enterEventMode;
    (void)terminateSimulation;
    return (fmi3Status)unsupported(C3, "model exchange");
}
fmi3Status fmi3SetTime(fmi3Instance instance_, fmi3Float64 time) {
    (void)time;
    return (fmi3Status)unsupported(C3, "model exchange");
}
fmi3Status fmi3SetContinuousStates(fmi3Instance instance_, const fmi3Float64 states[],
                                   size_t n) {
    (void)states;
    (void)n;
    return (fmi3Status)unsupported(C3, "model exchange");
}
fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance_, fmi3Float64 d[], size_t n) {
    (void)d;
    (void)n;
    return (fmi3Status)unsupported(C3, "model exchange");
}
fmi3Status fmi3GetEventIndicators(fmi3Instance instance_, fmi3Float64 e[], size_t n) {
    (void)e;
    (void)n;
    return (fmi3Status)unsupported(C3, "model exchange");
}
fmi3Status fmi3GetContinuousStates(fmi3Instance instance_, fmi3Float64 x[], size_t n) {
    (void)x;
    (void)n;
    return (fmi3Status)unsupported(C3, "model exchange");
}
fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance_, fmi3Float64 x[], size_t n) {
    (void)x;
    (void)n;
    return (fmi3Status)unsupported(C3, "model exchange");
}
fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance_, size_t *n) {
    if (!instance_ || !n) return fmi3Error;
    *n = 0;
    return fmi3OK;
}
fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance_, size_t *n) {
    if (!instance_ || !n) return fmi3Error;
    *n = 0;
    return fmi3OK;
}

fmi3Status fmi3EnterStepMode(fmi3Instance instance_) {
    if (!instance_) return fmi3Error;
    C3->mode = MODE_STEP;
    return fmi3OK;
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance_, const fmi3ValueReference vr[],
                                    size_t nvr, const fmi3Int32 orders[], fmi3Float64 values[],
                                    size_t nValues) {
    (void)vr;
    (void)nvr;
    (void)orders;
    (void)values;
    (void)nValues;
    return (fmi3Status)unsupported(C3, "fmi3GetOutputDerivatives");
}

fmi3Status fmi3DoStep(fmi3Instance instance_, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    int status;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!instance_) return fmi3Error;
    status = do_step(C3, currentCommunicationPoint, communicationStepSize);
    if (eventHandlingNeeded) *eventHandlingNeeded = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (earlyReturn) *earlyReturn = fmi3False;
    if (lastSuccessfulTime) *lastSuccessfulTime = C3->t;
    return (fmi3Status)status;
}

fmi3Status fmi3ActivateModelPartition(fmi3Instance instance_, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime) {
    (void)clockReference;
    (void)activationTime;
    return (fmi3Status)unsupported(C3, "scheduled execution");
}
