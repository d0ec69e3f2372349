/* A minimal FMI 2.0 co-simulation master for bench_fmu_step.py: the same C loop for every FMU.
 *
 * usage: fmu_step_harness BINARY RESOURCE_URI GUID STEP N VR_IN... -- VR_OUT...
 * Instantiates the FMU, then N times: fmi2SetReal (inputs at a varying value), fmi2DoStep,
 * fmi2GetReal; prints the nanoseconds per doStep and per whole iteration (medians are not
 * needed: one loop of N steps, timed as a whole and doStep alone).
 */
#define _POSIX_C_SOURCE 199309L
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "fmi2Functions.h"

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status,
                   fmi2String category, fmi2String message, ...) {
    (void)env;
    (void)category;
    if (status >= fmi2Warning) fprintf(stderr, "[%s] %s\n", name, message);
}

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

#define LOAD(name) name##TYPE *name = (name##TYPE *)dlsym(lib, #name)

int main(int argc, char **argv) {
    void *lib;
    fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    fmi2ValueReference vin[64], vout[64];
    fmi2Real uin[64], yout[64];
    int nin = 0, nout = 0, k, i, out = 0;
    double h, t = 0.0, t_step = 0.0, t0, t1, t2;
    long n;
    if (argc < 7) return 2;
    if (getenv("HARNESS_PRELOAD")) /* a pythonfmu binary needs libpython's symbols global */
        if (!dlopen(getenv("HARNESS_PRELOAD"), RTLD_NOW | RTLD_GLOBAL)) {
            fprintf(stderr, "%s\n", dlerror());
            return 1;
        }
    lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!lib) {
        fprintf(stderr, "%s\n", dlerror());
        return 1;
    }
    h = atof(argv[4]);
    n = atol(argv[5]);
    for (i = 6; i < argc; i++) {
        if (strcmp(argv[i], "--") == 0) out = 1;
        else if (out) vout[nout++] = (fmi2ValueReference)atoi(argv[i]);
        else vin[nin++] = (fmi2ValueReference)atoi(argv[i]);
    }
    {
        LOAD(fmi2Instantiate);
        LOAD(fmi2SetupExperiment);
        LOAD(fmi2EnterInitializationMode);
        LOAD(fmi2ExitInitializationMode);
        LOAD(fmi2SetReal);
        LOAD(fmi2GetReal);
        LOAD(fmi2DoStep);
        LOAD(fmi2Terminate);
        LOAD(fmi2FreeInstance);
        fmi2Component c = fmi2Instantiate("bench", fmi2CoSimulation, argv[3], argv[2], &cb,
                                          fmi2False, fmi2False);
        if (!c) return 1;
        fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0);
        fmi2EnterInitializationMode(c);
        fmi2ExitInitializationMode(c);
        t0 = now();
        for (k = 0; k < n; k++) {
            for (i = 0; i < nin; i++) uin[i] = 100.0 + 5.0 * ((k / 7 + i) % 5);
            fmi2SetReal(c, vin, nin, uin);
            t1 = now();
            if (fmi2DoStep(c, t, h, fmi2True) != fmi2OK) {
                fmi2Terminate(c);
                fmi2FreeInstance(c);
                return 1;
            }
            t2 = now();
            t_step += t2 - t1;
            fmi2GetReal(c, vout, nout, yout);
            t += h;
        }
        t2 = now();
        printf("%.1f %.1f\n", t_step / n * 1e9, (t2 - t0) / n * 1e9);
        fmi2Terminate(c);
        fmi2FreeInstance(c);
    }
    return 0;
}
