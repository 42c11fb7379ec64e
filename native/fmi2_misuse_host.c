/*
 * A careless FMI 2.0 host in C, for tests/test_native.py: what the FMI standard leaves
 * undefined, done on purpose, and memory measured over many instantiate/free cycles.
 *
 *   fmi2_misuse_host LIBRARY RESOURCES DT CYCLES
 *
 * LIBRARY is the FMU's binaries/linux64/<modelIdentifier>.so, RESOURCES its resources folder,
 * DT a step size the FMU accepts. In this order, each with the status it must return:
 *  - a doStep at t = 5 s when the instance is at t = DT (fmi2Error), then the right one (fmi2OK);
 *  - fmi2FreeInstance twice (no crash), then doStep, setReal, getReal, terminate,
 *    setDebugLogging and getRealStatus on the freed instance (fmi2Error each);
 *  - a new instance (whose memory may be the freed one's): the freed handle still gets
 *    fmi2Error and the new instance still steps (fmi2OK);
 *  - CYCLES life cycles (instantiate, setup, initialise, one step, terminate, free), the
 *    resident set size printed after the first tenth of them and after all.
 * It prints one line per check ("check NAME STATUS") and the line
 * "rss_kb WARM END CYCLES WARM_CYCLES"; the FMU's messages go to stderr.
 *
 * Exit status: 0 every check returned what it must; 1 a check did not; 2 usage or dlopen.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "fmi2Functions.h"

static void logger(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status,
                   fmi2String category, fmi2String message, ...)
{
    (void)env;
    fprintf(stderr, "[%s] status %d %s: %s\n", instance ? instance : "?", (int)status,
            category ? category : "", message ? message : "");
}

static int failures;

static void expect(const char *name, fmi2Status got, fmi2Status want)
{
    printf("check %s %d\n", name, (int)got);
    if (got != want) {
        fprintf(stderr, "fmi2_misuse_host: %s returned %d, not %d\n", name, (int)got, (int)want);
        failures++;
    }
}

static long rss_kb(void)
{
    long pages = 0, resident = 0;
    FILE *f = fopen("/proc/self/statm", "r");
    if (!f) return -1;
    if (fscanf(f, "%ld %ld", &pages, &resident) != 2) resident = -1;
    fclose(f);
    return resident < 0 ? -1 : resident * (sysconf(_SC_PAGESIZE) / 1024);
}

#define LOAD(name)                                                             \
    name##TYPE *name = (name##TYPE *)dlsym(lib, #name);                        \
    if (!name) { fprintf(stderr, "fmi2_misuse_host: %s\n", dlerror()); return 2; }

int main(int argc, char **argv)
{
    if (argc != 5) {
        fprintf(stderr, "usage: %s LIBRARY RESOURCES DT CYCLES\n", argv[0]);
        return 2;
    }
    double dt = strtod(argv[3], NULL);
    long cycles = strtol(argv[4], NULL, 10);
    void *lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!lib) { fprintf(stderr, "fmi2_misuse_host: %s\n", dlerror()); return 2; }
    LOAD(fmi2Instantiate) LOAD(fmi2SetupExperiment) LOAD(fmi2EnterInitializationMode)
    LOAD(fmi2ExitInitializationMode) LOAD(fmi2SetReal) LOAD(fmi2GetReal) LOAD(fmi2DoStep)
    LOAD(fmi2Terminate) LOAD(fmi2FreeInstance) LOAD(fmi2SetDebugLogging) LOAD(fmi2GetRealStatus)

    char uri[4096];
    snprintf(uri, sizeof uri, "file://%s", argv[2]);
    fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};
    fmi2ValueReference vr = 0;
    fmi2Real x = 0.0;

    fmi2Component c = fmi2Instantiate("careless", fmi2CoSimulation, "", uri, &callbacks,
                                      fmi2False, fmi2False);
    if (!c) { fprintf(stderr, "fmi2_misuse_host: fmi2Instantiate failed\n"); return 1; }
    expect("setup", fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0), fmi2OK);
    expect("enter_init", fmi2EnterInitializationMode(c), fmi2OK);
    expect("exit_init", fmi2ExitInitializationMode(c), fmi2OK);
    expect("step_at_0", fmi2DoStep(c, 0.0, dt, fmi2True), fmi2OK);
    expect("step_at_wrong_time", fmi2DoStep(c, 5.0, dt, fmi2True), fmi2Error);
    expect("step_at_dt", fmi2DoStep(c, dt, dt, fmi2True), fmi2OK);
    expect("terminate", fmi2Terminate(c), fmi2OK);
    fmi2FreeInstance(c);
    fmi2FreeInstance(c);                      /* the double free: must not crash */
    printf("check double_free survived\n");
    expect("step_after_free", fmi2DoStep(c, 2 * dt, dt, fmi2True), fmi2Error);
    expect("set_real_after_free", fmi2SetReal(c, &vr, 1, &x), fmi2Error);
    expect("get_real_after_free", fmi2GetReal(c, &vr, 1, &x), fmi2Error);
    expect("terminate_after_free", fmi2Terminate(c), fmi2Error);
    expect("debug_logging_after_free", fmi2SetDebugLogging(c, fmi2True, 0, NULL), fmi2Error);
    expect("real_status_after_free", fmi2GetRealStatus(c, fmi2LastSuccessfulTime, &x), fmi2Error);

    fmi2Component d = fmi2Instantiate("next", fmi2CoSimulation, "", uri, &callbacks,
                                      fmi2False, fmi2False);
    if (!d) { fprintf(stderr, "fmi2_misuse_host: fmi2Instantiate failed\n"); return 1; }
    expect("freed_handle_beside_new", fmi2DoStep(c, 0.0, dt, fmi2True), fmi2Error);
    expect("new_setup", fmi2SetupExperiment(d, fmi2False, 0.0, 0.0, fmi2False, 0.0), fmi2OK);
    expect("new_enter_init", fmi2EnterInitializationMode(d), fmi2OK);
    expect("new_exit_init", fmi2ExitInitializationMode(d), fmi2OK);
    expect("new_step", fmi2DoStep(d, 0.0, dt, fmi2True), fmi2OK);
    fmi2FreeInstance(d);

    long warm_cycles = cycles / 10, warm = -1;
    for (long k = 0; k < cycles && failures == 0; k++) {
        if (k == warm_cycles) warm = rss_kb();
        fmi2Component e = fmi2Instantiate("cycle", fmi2CoSimulation, "", uri, &callbacks,
                                          fmi2False, fmi2False);
        if (!e) { fprintf(stderr, "fmi2_misuse_host: fmi2Instantiate failed\n"); return 1; }
        if (fmi2SetupExperiment(e, fmi2False, 0.0, 0.0, fmi2False, 0.0) != fmi2OK
            || fmi2EnterInitializationMode(e) != fmi2OK || fmi2ExitInitializationMode(e) != fmi2OK
            || fmi2DoStep(e, 0.0, dt, fmi2True) != fmi2OK || fmi2Terminate(e) != fmi2OK) {
            fprintf(stderr, "fmi2_misuse_host: cycle %ld failed\n", k);
            failures++;
        }
        fmi2FreeInstance(e);
    }
    printf("rss_kb %ld %ld %ld %ld\n", warm, rss_kb(), cycles, warm_cycles);
    fflush(stdout);
    return failures ? 1 : 0;   /* the library stays loaded: the FMU's Python stays running */
}
