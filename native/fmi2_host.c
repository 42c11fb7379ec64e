/*
 * A minimal FMI 2.0 co-simulation host in C: the whole life cycle of one FMU instance, then a
 * normal process exit. Used by tests/test_native.py and benchmarks/native_overhead.py, and an
 * example of how a C tool loads our FMUs (native/README.md has the recipe).
 *
 *   fmi2_host LIBRARY RESOURCES STEPS DT [VR=VALUE ...] [VR ...] [--repeat N]
 *
 * LIBRARY is the FMU's binaries/linux64/<modelIdentifier>.so, RESOURCES its resources folder.
 * It instantiates, sets up the experiment at t = 0, enters initialization mode, sets the Real
 * inputs VR=VALUE, exits initialization mode, then STEPS times: sets the inputs again, does a
 * step of DT from t = k * DT and prints the Reals VR ... (C99 hex floats, exact) on one line;
 * then terminates, frees the instance and unloads the library. With --repeat N (default 1)
 * the whole life cycle runs N times in the process (the library is loaded and unloaded each
 * time). With --time it prints, instead of values, the mean wall time in microseconds of one
 * setReal + doStep + getReal.
 *
 * Exit status: 0 all calls returned fmi2OK; 1 an FMI call failed; 2 usage, dlopen or dlsym
 * error; 3 dlclose failed or did not unload the library.
 */
#define _GNU_SOURCE     /* RTLD_NOLOAD */
#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "fmi2Functions.h"

static void logger(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status,
                   fmi2String category, fmi2String message, ...)
{
    (void)env;
    /* the message is printed as is, not as a printf format (our FMUs send plain text) */
    fprintf(stderr, "[%s] status %d %s: ", instance ? instance : "?", (int)status,
            category ? category : "");
    fputs(message ? message : "", stderr);
    fputc('\n', stderr);
}

#define MAX_VARS 256

static int check(fmi2Status status, const char *what)
{
    if (status == fmi2OK) return 0;
    fprintf(stderr, "fmi2_host: %s returned status %d\n", what, (int)status);
    return 1;
}

static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

#define LOAD(name)                                                             \
    name##TYPE *name = (name##TYPE *)dlsym(lib, #name);                        \
    if (!name) { fprintf(stderr, "fmi2_host: %s\n", dlerror()); dlclose(lib); return 2; }

/* One life cycle; the return value is the process exit status. */
static int run(const char *library, const char *resources, long steps, double dt,
               const fmi2ValueReference *in_vr, const fmi2Real *in_value, size_t n_in,
               const fmi2ValueReference *out_vr, size_t n_out, int timing)
{
    void *lib = dlopen(library, RTLD_NOW | RTLD_LOCAL);
    if (!lib) { fprintf(stderr, "fmi2_host: %s\n", dlerror()); return 2; }
    LOAD(fmi2Instantiate) LOAD(fmi2SetupExperiment) LOAD(fmi2EnterInitializationMode)
    LOAD(fmi2ExitInitializationMode) LOAD(fmi2SetReal) LOAD(fmi2GetReal) LOAD(fmi2DoStep)
    LOAD(fmi2Terminate) LOAD(fmi2FreeInstance)

    char uri[4096];
    snprintf(uri, sizeof uri, "file://%s", resources);
    fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};
    int failed = 0;
    fmi2Component c = fmi2Instantiate("host", fmi2CoSimulation, "", uri, &callbacks,
                                      fmi2False, fmi2True);
    if (!c) {
        fprintf(stderr, "fmi2_host: fmi2Instantiate failed\n");
        failed = 1;
    } else {
        fmi2Real out[MAX_VARS];
        failed |= check(fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0), "fmi2SetupExperiment");
        failed |= check(fmi2EnterInitializationMode(c), "fmi2EnterInitializationMode");
        if (n_in) failed |= check(fmi2SetReal(c, in_vr, n_in, in_value), "fmi2SetReal");
        failed |= check(fmi2ExitInitializationMode(c), "fmi2ExitInitializationMode");
        double t0 = now();
        for (long k = 0; k < steps && !failed; k++) {
            if (n_in) failed |= check(fmi2SetReal(c, in_vr, n_in, in_value), "fmi2SetReal");
            failed |= check(fmi2DoStep(c, k * dt, dt, fmi2True), "fmi2DoStep");
            if (n_out) failed |= check(fmi2GetReal(c, out_vr, n_out, out), "fmi2GetReal");
            for (size_t i = 0; i < n_out && !timing; i++)
                printf(i + 1 < n_out ? "%a " : "%a\n", out[i]);
        }
        if (timing && !failed) printf("%.4f\n", 1e6 * (now() - t0) / (steps > 0 ? steps : 1));
        failed |= check(fmi2Terminate(c), "fmi2Terminate");
        fmi2FreeInstance(c);
    }
    if (dlclose(lib) != 0) {
        fprintf(stderr, "fmi2_host: dlclose: %s\n", dlerror());
        return 3;
    }
    void *still = dlopen(library, RTLD_NOW | RTLD_NOLOAD);
    if (still) {
        fprintf(stderr, "fmi2_host: %s is still loaded after dlclose\n", library);
        dlclose(still);
        return 3;
    }
    return failed;
}

int main(int argc, char **argv)
{
    if (argc < 5) {
        fprintf(stderr, "usage: %s LIBRARY RESOURCES STEPS DT [VR=VALUE ...] [VR ...] "
                        "[--repeat N] [--time]\n", argv[0]);
        return 2;
    }
    fmi2ValueReference in_vr[MAX_VARS], out_vr[MAX_VARS];
    fmi2Real in_value[MAX_VARS];
    size_t n_in = 0, n_out = 0;
    long repeat = 1;
    int timing = 0;
    for (int i = 5; i < argc; i++) {
        char *eq = strchr(argv[i], '=');
        if (strcmp(argv[i], "--repeat") == 0 && i + 1 < argc) {
            repeat = strtol(argv[++i], NULL, 10);
        } else if (strcmp(argv[i], "--time") == 0) {
            timing = 1;
        } else if (eq && n_in < MAX_VARS) {
            in_vr[n_in] = (fmi2ValueReference)strtoul(argv[i], NULL, 10);
            in_value[n_in++] = strtod(eq + 1, NULL);
        } else if (!eq && n_out < MAX_VARS) {
            out_vr[n_out++] = (fmi2ValueReference)strtoul(argv[i], NULL, 10);
        } else {
            fprintf(stderr, "fmi2_host: bad or too many arguments at %s\n", argv[i]);
            return 2;
        }
    }
    int status = 0;
    for (long r = 0; r < repeat && status == 0; r++)
        status = run(argv[1], argv[2], strtol(argv[3], NULL, 10), strtod(argv[4], NULL),
                     in_vr, in_value, n_in, out_vr, n_out, timing);
    fflush(stdout);
    return status;
}
