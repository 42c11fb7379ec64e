/*
 * FMI 3.0 co-simulation functions for an FMU whose model is a Python class (the same
 * pythonfmu Fmi2Slave subclasses as the FMI 2.0 FMUs), on top of our FMI 2.0 layer.
 *
 * This file includes fmi2_python.c: the FMI 3.0 library is the FMI 2.0 layer (its handle
 * table, the GIL, the slave's life cycle, the wrong-time doStep check, logging, FMU states)
 * with the FMI 3.0 entry points as thin translations in front of it. So there is one
 * implementation of how a Python slave is driven; only the calling convention differs:
 *
 *  - fmi3InstantiateCoSimulation: the resource *path* becomes the file URI fmi2Instantiate
 *    takes; the host's logMessage(instanceEnvironment, status, category, message) is reached
 *    through an fmi2 logger whose componentEnvironment is a Host3 (below). No Event Mode, no
 *    early return, no intermediate update (the modelDescription says so).
 *  - fmi3EnterInitializationMode = fmi2SetupExperiment + fmi2EnterInitializationMode.
 *  - Float64 = Real, Int32 = Integer, Boolean (bool) = Boolean (int, converted), String =
 *    String; the variables are scalars (nValues must equal nValueReferences). The FMU has no
 *    variable of the other FMI 3.0 types: a call for one is fmi3Error.
 *  - the independent variable `time` (FMI 3.0 requires one) has the value reference after the
 *    slave's last variable (len(slave.vars), as orchestration/fmi3.py declares it); reading it
 *    gives the last successful time (FMI 3.0, 2.4.7.4).
 *  - fmi3DoStep: fmi2DoStep, then no event, no termination, no early return and the last
 *    successful time.
 *
 * Only the fmi3* functions are exported (orchestration/native.py links with a version script);
 * the fmi2* ones are internal to the library. Messages name the FMI 3.0 function the host
 * called (FMI3_NAME_* below), except the slave's own (fmus/common/fmi.py).
 */
/* the FMI 3.0 function a message of the FMI 2.0 layer names (FMI_NAME in fmi2_python.c) */
#define FMI3_NAMES
#define FMI3_NAME_Instantiate "fmi3InstantiateCoSimulation"
#define FMI3_NAME_FreeInstance "fmi3FreeInstance"
#define FMI3_NAME_SetDebugLogging "fmi3SetDebugLogging"
#define FMI3_NAME_SetupExperiment "fmi3EnterInitializationMode"
#define FMI3_NAME_EnterInitializationMode "fmi3EnterInitializationMode"
#define FMI3_NAME_ExitInitializationMode "fmi3ExitInitializationMode"
#define FMI3_NAME_Terminate "fmi3Terminate"
#define FMI3_NAME_Reset "fmi3Reset"
#define FMI3_NAME_DoStep "fmi3DoStep"
#define FMI3_NAME_GetReal "fmi3GetFloat64"
#define FMI3_NAME_GetRealStatus "fmi3GetFloat64"        /* reads `time`, the last successful time */
#define FMI3_NAME_SetReal "fmi3SetFloat64"
#define FMI3_NAME_GetInteger "fmi3GetInt32"
#define FMI3_NAME_SetInteger "fmi3SetInt32"
#define FMI3_NAME_GetBoolean "fmi3GetBoolean"
#define FMI3_NAME_SetBoolean "fmi3SetBoolean"
#define FMI3_NAME_GetString "fmi3GetString"
#define FMI3_NAME_SetString "fmi3SetString"
#define FMI3_NAME_GetFMUstate "fmi3GetFMUState"
#define FMI3_NAME_SetFMUstate "fmi3SetFMUState"
#define FMI3_NAME_SerializedFMUstateSize "fmi3SerializedFMUStateSize"
#define FMI3_NAME_SerializeFMUstate "fmi3SerializeFMUState"
#define FMI3_NAME_DeSerializeFMUstate "fmi3DeserializeFMUState"
/* FMI 2.0 functions no FMI 3.0 call reaches */
#define FMI3_NAME_GetStatus "fmi2GetStatus"
#define FMI3_NAME_GetIntegerStatus "fmi2GetIntegerStatus"
#define FMI3_NAME_GetBooleanStatus "fmi2GetBooleanStatus"
#define FMI3_NAME_GetStringStatus "fmi2GetStringStatus"
#define FMI3_NAME_GetDirectionalDerivative "fmi2GetDirectionalDerivative"
#define FMI3_NAME_SetRealInputDerivatives "fmi2SetRealInputDerivatives"
#define FMI3_NAME_GetRealOutputDerivatives "fmi2GetRealOutputDerivatives"
#define FMI3_NAME_CancelStep "fmi2CancelStep"
#include "fmi2_python.c"

#include "fmi3Functions.h"

/* What an FMI 3.0 instance has beyond the FMI 2.0 one: the host's logger and environment. */
typedef struct {
    fmi3InstanceEnvironment environment;
    fmi3LogMessageCallback log_message;
    fmi3ValueReference time_vr;           /* the independent variable's value reference */
} Host3;

/* The fmi2 logger of an FMI 3.0 instance: the message goes to the host's logMessage. */
static void log3(fmi2ComponentEnvironment env, fmi2String instance_name, fmi2Status status,
                 fmi2String category, fmi2String message, ...)
{
    (void)instance_name;   /* FMI 3.0's logger has none: the environment says which instance */
    const Host3 *host = env;
    if (host && host->log_message)
        host->log_message(host->environment, (fmi3Status)status, category, message);
}

/* The Host3 of a live instance, or NULL (reported on stderr as fmi2's lookup does). */
static Host3 *host_of(fmi3Instance c, const char *function)
{
    Instance *in = lookup(c, function);
    return in ? (Host3 *)in->functions.componentEnvironment : NULL;
}

/* A message to the host about instance `c` (live: checked by the caller). */
static fmi3Status refuse(fmi3Instance c, const char *function, const char *why)
{
    Instance *in = lookup(c, function);
    if (!in) return fmi3Error;
    char buffer[320];
    snprintf(buffer, sizeof buffer, "%s: %s", function, why);
    emit(in, fmi2Error, "logStatusError", buffer);
    return fmi3Error;
}

/* "file://" + the path, '%' escaped (fmi2's local_path decodes %XX). */
static char *file_uri(const char *path)
{
    size_t n = strlen(path), extra = 0;
    for (const char *p = path; *p; p++) extra += (*p == '%') ? 2 : 0;
    char *uri = malloc(7 + n + extra + 1), *out = uri;
    if (!uri) return NULL;
    memcpy(out, "file://", 7);
    out += 7;
    for (const char *p = path; *p; p++) {
        if (*p == '%') { memcpy(out, "%25", 3); out += 3; }
        else *out++ = *p;
    }
    *out = '\0';
    return uri;
}

FMI3_Export const char *fmi3GetVersion(void) { return fmi3Version; }

FMI3_Export fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn,
                                           size_t nCategories, const fmi3String categories[])
{
    return (fmi3Status)fmi2SetDebugLogging(instance, loggingOn ? fmi2True : fmi2False,
                                           nCategories, categories);
}

FMI3_Export fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName,
        fmi3String instantiationToken, fmi3String resourcePath, fmi3Boolean visible,
        fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
        fmi3LogMessageCallback logMessage)
{
    (void)instantiationToken; (void)resourcePath; (void)visible; (void)loggingOn;
    if (logMessage) logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                               "fmi3InstantiateModelExchange: this FMU supports co-simulation only");
    (void)instanceName;
    return NULL;
}

FMI3_Export fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName,
        fmi3String instantiationToken, fmi3String resourcePath, fmi3Boolean visible,
        fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
        fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
        fmi3LockPreemptionCallback lockPreemption, fmi3UnlockPreemptionCallback unlockPreemption)
{
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible;
    (void)loggingOn; (void)clockUpdate; (void)lockPreemption; (void)unlockPreemption;
    if (logMessage) logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                               "fmi3InstantiateScheduledExecution: this FMU supports co-simulation only");
    return NULL;
}

FMI3_Export fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName,
        fmi3String instantiationToken, fmi3String resourcePath, fmi3Boolean visible,
        fmi3Boolean loggingOn, fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
        const fmi3ValueReference requiredIntermediateVariables[],
        size_t nRequiredIntermediateVariables, fmi3InstanceEnvironment instanceEnvironment,
        fmi3LogMessageCallback logMessage, fmi3IntermediateUpdateCallback intermediateUpdate)
{
    /* early return and intermediate updates are never used: each step ends where asked */
    (void)earlyReturnAllowed; (void)requiredIntermediateVariables;
    (void)nRequiredIntermediateVariables; (void)intermediateUpdate;
    Host3 *host = calloc(1, sizeof *host);
    if (!host) return NULL;
    host->environment = instanceEnvironment;
    host->log_message = logMessage;
    const char *why = eventModeUsed ? "fmi3InstantiateCoSimulation: this FMU has no Event Mode "
                                      "(hasEventMode=\"false\"): eventModeUsed must be false"
                    : !resourcePath ? "fmi3InstantiateCoSimulation: no resource path given" : NULL;
    if (why) {
        log3(host, instanceName, fmi2Error, "logStatusError", why);
        free(host);
        return NULL;
    }
    char *uri = file_uri(resourcePath);
    fmi2CallbackFunctions functions = {log3, NULL, NULL, NULL, host};
    fmi2Component c = uri ? fmi2Instantiate(instanceName, fmi2CoSimulation, instantiationToken,
                                            uri, &functions, visible ? fmi2True : fmi2False,
                                            loggingOn ? fmi2True : fmi2False) : NULL;
    free(uri);
    if (!c) { free(host); return NULL; }
    Instance *in = lookup(c, "fmi3InstantiateCoSimulation");
    PyGILState_STATE gil = PyGILState_Ensure();
    PyObject *vars = PyObject_GetAttrString(in->slave, "vars");
    Py_ssize_t n = vars ? PyObject_Length(vars) : -1;
    Py_XDECREF(vars);
    if (n < 0) report_exception(in, "fmi3InstantiateCoSimulation");
    PyGILState_Release(gil);
    if (n < 0) { fmi2FreeInstance(c); free(host); return NULL; }
    host->time_vr = (fmi3ValueReference)n;
    return c;
}

FMI3_Export void fmi3FreeInstance(fmi3Instance instance)
{
    if (!instance) return;
    void *host = NULL;
    pthread_mutex_lock(&registry_lock);
    for (size_t i = 0; i < n_live; i++) {
        if (live[i].handle == (uintptr_t)instance) { host = live[i].in->functions.componentEnvironment; break; }
    }
    pthread_mutex_unlock(&registry_lock);
    fmi2FreeInstance(instance);       /* a freed or foreign handle is refused there */
    free(host);
}

FMI3_Export fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined,
        fmi3Float64 tolerance, fmi3Float64 startTime, fmi3Boolean stopTimeDefined, fmi3Float64 stopTime)
{
    fmi2Status status = fmi2SetupExperiment(instance, toleranceDefined ? fmi2True : fmi2False, tolerance,
                                            startTime, stopTimeDefined ? fmi2True : fmi2False, stopTime);
    return (fmi3Status)(status > fmi2Warning ? status : fmi2EnterInitializationMode(instance));
}

FMI3_Export fmi3Status fmi3ExitInitializationMode(fmi3Instance instance)
{
    return (fmi3Status)fmi2ExitInitializationMode(instance);
}

FMI3_Export fmi3Status fmi3Terminate(fmi3Instance instance)
{
    return (fmi3Status)fmi2Terminate(instance);
}

FMI3_Export fmi3Status fmi3Reset(fmi3Instance instance)
{
    return (fmi3Status)fmi2Reset(instance);
}

FMI3_Export fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
        fmi3Float64 communicationStepSize, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
        fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
        fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime)
{
    fmi2Status status = fmi2DoStep(instance, currentCommunicationPoint, communicationStepSize,
                                   noSetFMUStatePriorToCurrentPoint ? fmi2True : fmi2False);
    if (eventHandlingNeeded) *eventHandlingNeeded = false;
    if (terminateSimulation) *terminateSimulation = false;
    if (earlyReturn) *earlyReturn = false;
    if (lastSuccessfulTime && status <= fmi2Discard) {
        fmi2Real t = currentCommunicationPoint;
        fmi2GetRealStatus(instance, fmi2LastSuccessfulTime, &t);
        *lastSuccessfulTime = t;
    }
    return (fmi3Status)status;
}

/* ---- values: scalars only ------------------------------------------------------------ */

static int scalars(fmi3Instance c, const char *function, size_t nvr, size_t n_values)
{
    if (nvr == n_values) return 1;
    char why[160];
    snprintf(why, sizeof why, "%zu values for %zu value references: this FMU's variables are "
             "all scalars", n_values, nvr);
    refuse(c, function, why);
    return 0;
}

FMI3_Export fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference vr[],
                                      size_t nvr, fmi3Float64 values[], size_t nValues)
{
    Host3 *host = host_of(instance, "fmi3GetFloat64");
    if (!host || !scalars(instance, "fmi3GetFloat64", nvr, nValues)) return fmi3Error;
    size_t i = 0;
    while (i < nvr && vr[i] != host->time_vr) i++;
    if (i == nvr) return (fmi3Status)fmi2GetReal(instance, vr, nvr, values);
    /* `time` among them: one at a time (rare: a host recording the independent variable) */
    fmi2Status worst = fmi2OK;
    for (i = 0; i < nvr; i++) {
        fmi2Status s = vr[i] == host->time_vr
            ? fmi2GetRealStatus(instance, fmi2LastSuccessfulTime, &values[i])
            : fmi2GetReal(instance, &vr[i], 1, &values[i]);
        if (s > worst) worst = s;
        if (worst > fmi2Warning) break;
    }
    return (fmi3Status)worst;
}

FMI3_Export fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference vr[],
                                      size_t nvr, const fmi3Float64 values[], size_t nValues)
{
    if (!scalars(instance, "fmi3SetFloat64", nvr, nValues)) return fmi3Error;
    return (fmi3Status)fmi2SetReal(instance, vr, nvr, values);
}

/* fmi3Int32 and fmi2Integer are both 32-bit ints */
typedef char int32_is_fmi2Integer[sizeof(fmi3Int32) == sizeof(fmi2Integer) ? 1 : -1];

FMI3_Export fmi3Status fmi3GetInt32(fmi3Instance instance, const fmi3ValueReference vr[],
                                    size_t nvr, fmi3Int32 values[], size_t nValues)
{
    if (!scalars(instance, "fmi3GetInt32", nvr, nValues)) return fmi3Error;
    return (fmi3Status)fmi2GetInteger(instance, vr, nvr, (fmi2Integer *)values);
}

FMI3_Export fmi3Status fmi3SetInt32(fmi3Instance instance, const fmi3ValueReference vr[],
                                    size_t nvr, const fmi3Int32 values[], size_t nValues)
{
    if (!scalars(instance, "fmi3SetInt32", nvr, nValues)) return fmi3Error;
    return (fmi3Status)fmi2SetInteger(instance, vr, nvr, (const fmi2Integer *)values);
}

FMI3_Export fmi3Status fmi3GetBoolean(fmi3Instance instance, const fmi3ValueReference vr[],
                                      size_t nvr, fmi3Boolean values[], size_t nValues)
{
    if (!scalars(instance, "fmi3GetBoolean", nvr, nValues)) return fmi3Error;
    fmi2Boolean *b = calloc(nvr ? nvr : 1, sizeof *b);
    if (!b) return fmi3Error;
    fmi2Status status = fmi2GetBoolean(instance, vr, nvr, b);
    for (size_t i = 0; status <= fmi2Warning && i < nvr; i++) values[i] = b[i] != fmi2False;
    free(b);
    return (fmi3Status)status;
}

FMI3_Export fmi3Status fmi3SetBoolean(fmi3Instance instance, const fmi3ValueReference vr[],
                                      size_t nvr, const fmi3Boolean values[], size_t nValues)
{
    if (!scalars(instance, "fmi3SetBoolean", nvr, nValues)) return fmi3Error;
    fmi2Boolean *b = calloc(nvr ? nvr : 1, sizeof *b);
    if (!b) return fmi3Error;
    for (size_t i = 0; i < nvr; i++) b[i] = values[i] ? fmi2True : fmi2False;
    fmi2Status status = fmi2SetBoolean(instance, vr, nvr, b);
    free(b);
    return (fmi3Status)status;
}

FMI3_Export fmi3Status fmi3GetString(fmi3Instance instance, const fmi3ValueReference vr[],
                                     size_t nvr, fmi3String values[], size_t nValues)
{
    if (!scalars(instance, "fmi3GetString", nvr, nValues)) return fmi3Error;
    return (fmi3Status)fmi2GetString(instance, vr, nvr, values);
}

FMI3_Export fmi3Status fmi3SetString(fmi3Instance instance, const fmi3ValueReference vr[],
                                     size_t nvr, const fmi3String values[], size_t nValues)
{
    if (!scalars(instance, "fmi3SetString", nvr, nValues)) return fmi3Error;
    return (fmi3Status)fmi2SetString(instance, vr, nvr, values);
}

/* The types no variable of this FMU has: fmi3Error, naming the function. */
#define NO_SUCH_TYPE(Name, Type)                                                                  \
    FMI3_Export fmi3Status fmi3Get##Name(fmi3Instance instance, const fmi3ValueReference vr[],   \
                                         size_t nvr, Type values[], size_t nValues)              \
    {                                                                                             \
        (void)vr; (void)nvr; (void)values; (void)nValues;                                         \
        return refuse(instance, "fmi3Get" #Name, "this FMU has no variable of this type");       \
    }                                                                                             \
    FMI3_Export fmi3Status fmi3Set##Name(fmi3Instance instance, const fmi3ValueReference vr[],   \
                                         size_t nvr, const Type values[], size_t nValues)        \
    {                                                                                             \
        (void)vr; (void)nvr; (void)values; (void)nValues;                                         \
        return refuse(instance, "fmi3Set" #Name, "this FMU has no variable of this type");       \
    }
NO_SUCH_TYPE(Float32, fmi3Float32)
NO_SUCH_TYPE(Int8, fmi3Int8)
NO_SUCH_TYPE(UInt8, fmi3UInt8)
NO_SUCH_TYPE(Int16, fmi3Int16)
NO_SUCH_TYPE(UInt16, fmi3UInt16)
NO_SUCH_TYPE(UInt32, fmi3UInt32)
NO_SUCH_TYPE(Int64, fmi3Int64)
NO_SUCH_TYPE(UInt64, fmi3UInt64)

FMI3_Export fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                     size_t valueSizes[], fmi3Binary values[], size_t nValues)
{
    (void)vr; (void)nvr; (void)valueSizes; (void)values; (void)nValues;
    return refuse(instance, "fmi3GetBinary", "this FMU has no variable of this type");
}

FMI3_Export fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                     const size_t valueSizes[], const fmi3Binary values[], size_t nValues)
{
    (void)vr; (void)nvr; (void)valueSizes; (void)values; (void)nValues;
    return refuse(instance, "fmi3SetBinary", "this FMU has no variable of this type");
}

FMI3_Export fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                    fmi3Clock values[])
{
    (void)vr; (void)nvr; (void)values;
    return refuse(instance, "fmi3GetClock", "this FMU has no clocks");
}

FMI3_Export fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                    const fmi3Clock values[])
{
    (void)vr; (void)nvr; (void)values;
    return refuse(instance, "fmi3SetClock", "this FMU has no clocks");
}

/* ---- FMU state: the FMI 2.0 layer's (the slave's data-only state) --------------------- */

FMI3_Export fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState)
{
    return (fmi3Status)fmi2GetFMUstate(instance, FMUState);
}

FMI3_Export fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState)
{
    return (fmi3Status)fmi2SetFMUstate(instance, FMUState);
}

FMI3_Export fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState)
{
    return (fmi3Status)fmi2FreeFMUstate(instance, FMUState);
}

FMI3_Export fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState,
                                                  size_t *size)
{
    return (fmi3Status)fmi2SerializedFMUstateSize(instance, FMUState, size);
}

FMI3_Export fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState,
                                             fmi3Byte serializedState[], size_t size)
{
    return (fmi3Status)fmi2SerializeFMUstate(instance, FMUState, (fmi2Byte *)serializedState, size);
}

FMI3_Export fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[],
                                               size_t size, fmi3FMUState *FMUState)
{
    return (fmi3Status)fmi2DeSerializeFMUstate(instance, (const fmi2Byte *)serializedState, size,
                                               FMUState);
}

/* ---- what the FMU does not support (its modelDescription says so) -------------------- */

#define UNSUPPORTED(call) return refuse(instance, call, "not supported by this FMU")

FMI3_Export fmi3Status fmi3EnterEventMode(fmi3Instance instance) { UNSUPPORTED("fmi3EnterEventMode"); }
FMI3_Export fmi3Status fmi3EnterStepMode(fmi3Instance instance) { UNSUPPORTED("fmi3EnterStepMode"); }
FMI3_Export fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) { UNSUPPORTED("fmi3EnterConfigurationMode"); }
FMI3_Export fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) { UNSUPPORTED("fmi3ExitConfigurationMode"); }
FMI3_Export fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) { UNSUPPORTED("fmi3EvaluateDiscreteStates"); }

FMI3_Export fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
        fmi3Boolean *terminateSimulation, fmi3Boolean *nominalsOfContinuousStatesChanged,
        fmi3Boolean *valuesOfContinuousStatesChanged, fmi3Boolean *nextEventTimeDefined,
        fmi3Float64 *nextEventTime)
{
    (void)discreteStatesNeedUpdate; (void)terminateSimulation; (void)nominalsOfContinuousStatesChanged;
    (void)valuesOfContinuousStatesChanged; (void)nextEventTimeDefined; (void)nextEventTime;
    UNSUPPORTED("fmi3UpdateDiscreteStates");
}

FMI3_Export fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance,
        fmi3ValueReference valueReference, size_t *nDependencies)
{
    (void)valueReference; (void)nDependencies;
    UNSUPPORTED("fmi3GetNumberOfVariableDependencies");
}

FMI3_Export fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
        size_t elementIndicesOfDependent[], fmi3ValueReference independents[],
        size_t elementIndicesOfIndependents[], fmi3DependencyKind dependencyKinds[], size_t nDependencies)
{
    (void)dependent; (void)elementIndicesOfDependent; (void)independents;
    (void)elementIndicesOfIndependents; (void)dependencyKinds; (void)nDependencies;
    UNSUPPORTED("fmi3GetVariableDependencies");
}

FMI3_Export fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
        size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
        size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity)
{
    (void)unknowns; (void)nUnknowns; (void)knowns; (void)nKnowns; (void)seed; (void)nSeed;
    (void)sensitivity; (void)nSensitivity;
    UNSUPPORTED("fmi3GetDirectionalDerivative");
}

FMI3_Export fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
        size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
        size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity)
{
    (void)unknowns; (void)nUnknowns; (void)knowns; (void)nKnowns; (void)seed; (void)nSeed;
    (void)sensitivity; (void)nSensitivity;
    UNSUPPORTED("fmi3GetAdjointDerivative");
}

FMI3_Export fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference vr[],
        size_t nvr, const fmi3Int32 orders[], fmi3Float64 values[], size_t nValues)
{
    (void)vr; (void)nvr; (void)orders; (void)values; (void)nValues;
    UNSUPPORTED("fmi3GetOutputDerivatives");
}

FMI3_Export fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference vr[],
        size_t nvr, fmi3Float64 intervals[], fmi3IntervalQualifier qualifiers[])
{
    (void)vr; (void)nvr; (void)intervals; (void)qualifiers;
    UNSUPPORTED("fmi3GetIntervalDecimal");
}

FMI3_Export fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference vr[],
        size_t nvr, fmi3UInt64 counters[], fmi3UInt64 resolutions[], fmi3IntervalQualifier qualifiers[])
{
    (void)vr; (void)nvr; (void)counters; (void)resolutions; (void)qualifiers;
    UNSUPPORTED("fmi3GetIntervalFraction");
}

FMI3_Export fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference vr[],
        size_t nvr, fmi3Float64 shifts[])
{
    (void)vr; (void)nvr; (void)shifts;
    UNSUPPORTED("fmi3GetShiftDecimal");
}

FMI3_Export fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference vr[],
        size_t nvr, fmi3UInt64 counters[], fmi3UInt64 resolutions[])
{
    (void)vr; (void)nvr; (void)counters; (void)resolutions;
    UNSUPPORTED("fmi3GetShiftFraction");
}

FMI3_Export fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference vr[],
        size_t nvr, const fmi3Float64 intervals[])
{
    (void)vr; (void)nvr; (void)intervals;
    UNSUPPORTED("fmi3SetIntervalDecimal");
}

FMI3_Export fmi3Status fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference vr[],
        size_t nvr, const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
{
    (void)vr; (void)nvr; (void)counters; (void)resolutions;
    UNSUPPORTED("fmi3SetIntervalFraction");
}

FMI3_Export fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference vr[],
        size_t nvr, const fmi3Float64 shifts[])
{
    (void)vr; (void)nvr; (void)shifts;
    UNSUPPORTED("fmi3SetShiftDecimal");
}

FMI3_Export fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference vr[],
        size_t nvr, const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
{
    (void)vr; (void)nvr; (void)counters; (void)resolutions;
    UNSUPPORTED("fmi3SetShiftFraction");
}

/* ---- Model Exchange and Scheduled Execution: not this FMU's interfaces ----------------
   (exported all the same: FMI 3.0 hosts such as fmpy load every function of the standard) */

FMI3_Export fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) { UNSUPPORTED("fmi3EnterContinuousTimeMode"); }

FMI3_Export fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
        fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation)
{
    (void)noSetFMUStatePriorToCurrentPoint; (void)enterEventMode; (void)terminateSimulation;
    UNSUPPORTED("fmi3CompletedIntegratorStep");
}

FMI3_Export fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time)
{
    (void)time;
    UNSUPPORTED("fmi3SetTime");
}

FMI3_Export fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
        size_t nContinuousStates)
{
    (void)continuousStates; (void)nContinuousStates;
    UNSUPPORTED("fmi3SetContinuousStates");
}

/* the functions of Model Exchange that read an array of n values */
#define ME_ARRAY(Name)                                                                            \
    FMI3_Export fmi3Status fmi3##Name(fmi3Instance instance, fmi3Float64 values[], size_t n)     \
    {                                                                                             \
        (void)values; (void)n;                                                                    \
        UNSUPPORTED("fmi3" #Name);                                                                \
    }
ME_ARRAY(GetContinuousStateDerivatives)
ME_ARRAY(GetEventIndicators)
ME_ARRAY(GetContinuousStates)
ME_ARRAY(GetNominalsOfContinuousStates)

FMI3_Export fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators)
{
    (void)nEventIndicators;
    UNSUPPORTED("fmi3GetNumberOfEventIndicators");
}

FMI3_Export fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates)
{
    (void)nContinuousStates;
    UNSUPPORTED("fmi3GetNumberOfContinuousStates");
}

FMI3_Export fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                                  fmi3Float64 activationTime)
{
    (void)clockReference; (void)activationTime;
    UNSUPPORTED("fmi3ActivateModelPartition");
}
