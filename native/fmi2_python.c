/*
 * FMI 2.0 co-simulation functions for an FMU whose model is a Python class (pythonfmu's
 * Fmi2Slave), in place of pythonfmu 0.7's native library (libpythonfmu-export.so).
 *
 * What it does, call by call, is what pythonfmu's library does (PySlaveInstance.cpp and
 * fmi2.cpp of pythonfmu 0.7): fmi2Instantiate puts the FMU's resources folder on sys.path,
 * imports the script named in resources/slavemodule.txt, instantiates its Fmi2Slave subclass
 * with the keyword arguments instance_name, resources, logger and visible, and every other
 * call forwards to the slave's method of the same name (setup_experiment, do_step, get_real,
 * set_real, _get_fmu_state, ...), draining the slave's log queue to the host's logger after
 * each call. A do_step that returns False is fmi2Discard, as in pythonfmu.
 *
 * What it does differently, on purpose (see native/README.md):
 *  - reference counting is exact: every new reference is released once, no borrowed
 *    reference is released (pythonfmu's findClass released the module dictionary it borrowed);
 *  - the interpreter is never finalised. If the host has no Python, the first fmi2Instantiate
 *    starts one and leaves it running until the process ends: finalising an interpreter that
 *    numpy/scipy were imported into is unsafe (their extension modules keep static state that
 *    does not survive Py_Finalize), and the FMU cannot know whether another FMU in the process
 *    still uses it. pythonfmu's finalisation from a static destructor read memory that other
 *    static destructors had already freed;
 *  - no static destructor, atexit hook or thread of this library touches Python, and no Python
 *    object points into this library (no C functions or types are handed to Python), so
 *    fmi2FreeInstance followed by dlclose is safe;
 *  - a Python exception is always sent to the host's logger as fmi2Error, whether or not
 *    debug logging is on; the slave's own messages of status error/fatal too, the others only
 *    when logging is on (and their category enabled by fmi2SetDebugLogging).
 *
 * The library is compiled against CPython's limited API (abi3, 3.11+) and does not link
 * libpython: the host provides it (a Python host has it; a C host preloads or links it).
 * Every entry point takes the GIL with PyGILState_Ensure, so any host thread may call it.
 */
#define PY_SSIZE_T_CLEAN
#define Py_LIMITED_API 0x030B0000
#include <Python.h>

#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

/* An FMI function's name in messages: FMI_NAME(DoStep) is "fmi2DoStep". The FMI 3.0 layer
   (fmi3_python.c), which includes this file, defines FMI3_NAMES and FMI3_NAME_<f> so that its
   messages name the FMI 3.0 function the host called. */
#ifdef FMI3_NAMES
#define FMI_NAME(f) FMI3_NAME_##f
#else
#define FMI_NAME(f) "fmi2" #f
#endif

/* The slave's methods, looked up once per instance (bound methods) in this order. */
enum Method {
    M_SETUP_EXPERIMENT, M_ENTER_INITIALIZATION_MODE, M_EXIT_INITIALIZATION_MODE, M_DO_STEP,
    M_TERMINATE, M_GET_REAL, M_GET_INTEGER, M_GET_BOOLEAN, M_GET_STRING, M_SET_REAL,
    M_SET_INTEGER, M_SET_BOOLEAN, M_SET_STRING, M_GET_FMU_STATE, M_SET_FMU_STATE,
    M_STATE_TO_BYTES, M_STATE_FROM_BYTES, N_METHODS
};
static const char *const METHOD_NAMES[N_METHODS] = {
    "setup_experiment", "enter_initialization_mode", "exit_initialization_mode", "do_step",
    "terminate", "get_real", "get_integer", "get_boolean", "get_string", "set_real",
    "set_integer", "set_boolean", "set_string", "_get_fmu_state", "_set_fmu_state",
    "_fmu_state_to_bytes", "_fmu_state_from_bytes",
};

typedef struct {
    char *instance_name;
    char *resources;                  /* local path of the FMU's resources folder */
    fmi2CallbackFunctions functions;  /* a copy: the host's struct need not outlive the call */
    int visible;
    int logging_on;
    char **categories;                /* enabled log categories; none = all */
    size_t n_categories;
    double last_successful_time;      /* also the time the next fmi2DoStep must start at */
    int time_known;                   /* 0 after fmi2SetFMUstate: the state's time is not kept */
    PyObject *slave_class;
    PyObject *slave;
    PyObject *log_queue;              /* the slave's list of LogMsg */
    PyObject *methods[N_METHODS];
    PyObject *strings;                /* keeps the last fmi2GetString results alive */
} Instance;

/* ---- live instances: a handle table -----------------------------------------------------
 *
 * The FMI standard leaves a call with a freed instance undefined; we refuse it. The host never
 * gets the address of an Instance: fmi2Instantiate returns a handle, a number that is never
 * handed out twice by this library (a 64-bit counter, salted with the library's own load
 * address so that two FMUs' libraries in one process give different handles), and every entry
 * point looks it up in the table of live instances before touching anything. A handle that is
 * not there (freed, never ours, or garbage) is never dereferenced, even if malloc has since
 * reused the freed Instance's memory for another instance: the call returns fmi2Error, and a
 * message goes to stderr (the freed instance's logger is not called: the host may have freed
 * its environment with it). The names of the last FREED_KEPT freed handles are kept (fixed
 * memory) to say which instance it was. The handles are non-canonical addresses on x86-64 and
 * AArch64, so a host that dereferences one faults at once instead of reading someone's memory.
 * A mutex guards the table (any host thread may call); a lookup is a lock, a scan of the live
 * instances (a few) and an unlock, well under a microsecond against a step's tens.
 */
#define FREED_KEPT 64
typedef struct { uintptr_t handle; Instance *in; } Live;
typedef struct { uintptr_t handle; char name[64]; } Freed;
static pthread_mutex_t registry_lock = PTHREAD_MUTEX_INITIALIZER;
static Live *live;                      /* the live instances (grown, never shrunk) */
static size_t n_live, live_capacity;
static Freed freed[FREED_KEPT];         /* a ring of the last freed handles */
static size_t n_freed;
static uint64_t handles_made;

static uintptr_t new_handle(void)
{
#if UINTPTR_MAX > 0xFFFFFFFFu
    const uintptr_t tag = (uintptr_t)0xFF1Fu << 48, bits = ((uintptr_t)1 << 48) - 1;
#else
    const uintptr_t tag = 0, bits = UINTPTR_MAX;
#endif
    uintptr_t salt = (uintptr_t)&registry_lock;
    handles_made++;
    return tag | ((salt + (uintptr_t)handles_made * 16) & bits & ~(uintptr_t)15);
}

/* Put `in` in the table; its handle, or NULL when out of memory. */
static fmi2Component register_instance(Instance *in)
{
    uintptr_t handle = 0;
    pthread_mutex_lock(&registry_lock);
    if (n_live == live_capacity) {
        size_t capacity = live_capacity ? 2 * live_capacity : 16;
        Live *grown = realloc(live, capacity * sizeof *grown);
        if (grown) { live = grown; live_capacity = capacity; }
    }
    if (n_live < live_capacity) {
        do handle = new_handle(); while (handle == 0);
        live[n_live].handle = handle;
        live[n_live++].in = in;
    }
    pthread_mutex_unlock(&registry_lock);
    return (fmi2Component)handle;
}

/* Why `c` is not a live instance, on stderr (the table's lock is held). */
static void report_stale(fmi2Component c, const char *function)
{
    uintptr_t handle = (uintptr_t)c;
    size_t kept = n_freed < FREED_KEPT ? n_freed : FREED_KEPT;
    for (size_t i = 0; i < kept; i++) {
        if (freed[i].handle == handle) {
            fprintf(stderr, "[%s] status %d logStatusError: %s: this instance was freed by "
                    FMI_NAME(FreeInstance) "; the call is refused\n", freed[i].name, (int)fmi2Error,
                    function);
            return;
        }
    }
    fprintf(stderr, "[?] status %d logStatusError: %s: %p is not a live instance of this FMU "
            "(%s); the call is refused\n", (int)fmi2Error, function, c,
            c ? "freed, or never returned by its " FMI_NAME(Instantiate) : "NULL");
}

/* The live instance of handle `c`, or NULL (reported) if it is not one. */
static Instance *lookup(fmi2Component c, const char *function)
{
    Instance *in = NULL;
    pthread_mutex_lock(&registry_lock);
    for (size_t i = 0; i < n_live; i++) {
        if (live[i].handle == (uintptr_t)c) { in = live[i].in; break; }
    }
    if (!in) report_stale(c, function);
    pthread_mutex_unlock(&registry_lock);
    return in;
}

/* Take `c` out of the table (remembering its name); its instance, or NULL (reported). */
static Instance *unregister_instance(fmi2Component c, const char *function)
{
    Instance *in = NULL;
    pthread_mutex_lock(&registry_lock);
    for (size_t i = 0; i < n_live; i++) {
        if (live[i].handle == (uintptr_t)c) {
            in = live[i].in;
            live[i] = live[--n_live];
            Freed *f = &freed[n_freed++ % FREED_KEPT];
            f->handle = (uintptr_t)c;
            snprintf(f->name, sizeof f->name, "%s", in->instance_name);
            break;
        }
    }
    if (!in) report_stale(c, function);
    pthread_mutex_unlock(&registry_lock);
    return in;
}

/* ---- logging ------------------------------------------------------------------------- */

static int category_enabled(const Instance *in, const char *category)
{
    if (in->n_categories == 0) return 1;
    for (size_t i = 0; i < in->n_categories; i++) {
        if (strcmp(in->categories[i], "logAll") == 0
            || (category && strcmp(in->categories[i], category) == 0)) return 1;
    }
    return 0;
}

/* Errors always reach the host; other messages only when it asked for them. The message is
   passed as is (no printf formatting), as pythonfmu does. */
static void emit(const Instance *in, fmi2Status status, const char *category, const char *message)
{
    if (in->functions.logger == NULL) return;
    if (status < fmi2Error && !(in->logging_on && category_enabled(in, category))) return;
    in->functions.logger(in->functions.componentEnvironment, in->instance_name, status,
                         category ? category : "", message);
}

/* A new UTF-8 copy of str(obj) (NULL if that fails; the Python error is cleared). */
static char *str_of(PyObject *obj)
{
    char *copy = NULL;
    PyObject *s = obj ? PyObject_Str(obj) : NULL;
    const char *utf8 = s ? PyUnicode_AsUTF8AndSize(s, NULL) : NULL;
    if (utf8) copy = strdup(utf8);
    Py_XDECREF(s);
    if (!copy) PyErr_Clear();
    return copy;
}

/* Send the messages the slave queued with Fmi2Slave.log to the host, then empty the queue. */
static void flush_log(Instance *in)
{
    if (in->log_queue == NULL) return;
    Py_ssize_t n = PyList_Size(in->log_queue);
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *msg = PyList_GetItem(in->log_queue, i);   /* borrowed */
        if (!msg) { PyErr_Clear(); break; }   /* the list shrank meanwhile */
        PyObject *status = PyObject_GetAttrString(msg, "status");
        PyObject *category = PyObject_GetAttrString(msg, "category");
        PyObject *text = PyObject_GetAttrString(msg, "msg");
        long s = status ? PyLong_AsLong(status) : (long)fmi2Error;
        char *c = (category && category != Py_None) ? str_of(category) : NULL;
        char *t = str_of(text);
        PyErr_Clear();
        if (s < fmi2OK || s > fmi2Pending) s = fmi2Error;
        emit(in, (fmi2Status)s, c, t ? t : "(unprintable log message)");
        free(c);
        free(t);
        Py_XDECREF(status);
        Py_XDECREF(category);
        Py_XDECREF(text);
    }
    if (n > 0 && PyList_SetSlice(in->log_queue, 0, n, NULL) < 0) PyErr_Clear();
    if (n < 0) PyErr_Clear();
}

/* "<ExceptionType>: <message> (<file>:<line>, in <function>)" of the innermost frame. */
static char *describe(PyObject *type, PyObject *value, PyObject *tb)
{
    char *text = NULL;
    PyObject *traceback = PyImport_ImportModule("traceback");
    PyObject *lines = traceback ? PyObject_CallMethod(traceback, "format_exception_only", "OO",
                                                     type, value ? value : Py_None) : NULL;
    PyObject *empty = PyUnicode_FromString("");
    PyObject *joined = (lines && empty) ? PyUnicode_Join(empty, lines) : NULL;
    PyObject *stripped = joined ? PyObject_CallMethod(joined, "strip", NULL) : NULL;
    PyObject *where = NULL;
    if (stripped && tb) {
        PyObject *frames = PyObject_CallMethod(traceback, "extract_tb", "O", tb);
        Py_ssize_t n = frames ? PySequence_Size(frames) : -1;
        PyObject *last = n > 0 ? PySequence_GetItem(frames, n - 1) : NULL;
        PyObject *file = last ? PyObject_GetAttrString(last, "filename") : NULL;
        PyObject *line = last ? PyObject_GetAttrString(last, "lineno") : NULL;
        PyObject *func = last ? PyObject_GetAttrString(last, "name") : NULL;
        if (file && line && func)
            where = PyUnicode_FromFormat("%S (%S:%S, in %S)", stripped, file, line, func);
        Py_XDECREF(frames);
        Py_XDECREF(last);
        Py_XDECREF(file);
        Py_XDECREF(line);
        Py_XDECREF(func);
    }
    text = str_of(where ? where : stripped);
    Py_XDECREF(where);
    Py_XDECREF(stripped);
    Py_XDECREF(joined);
    Py_XDECREF(empty);
    Py_XDECREF(lines);
    Py_XDECREF(traceback);
    PyErr_Clear();
    return text;
}

/* The pending Python exception of an FMI call, after what the slave logged, as fmi2Error. */
static fmi2Status report_exception(Instance *in, const char *function)
{
    PyObject *type, *value, *tb;
    PyErr_Fetch(&type, &value, &tb);
    PyErr_NormalizeException(&type, &value, &tb);
    flush_log(in);
    char *text = type ? describe(type, value, tb) : NULL;
    char buffer[2048];
    snprintf(buffer, sizeof buffer, "%s: %s", function, text ? text : "unknown Python error");
    emit(in, fmi2Error, "logStatusError", buffer);
    free(text);
    Py_XDECREF(type);
    Py_XDECREF(value);
    Py_XDECREF(tb);
    return fmi2Error;
}

/* The end of a call into Python: the slave's log, then fmi2OK, or the exception. */
static fmi2Status finish(Instance *in, const char *function, PyObject *result)
{
    if (result == NULL) return report_exception(in, function);
    Py_DECREF(result);
    flush_log(in);
    return fmi2OK;
}

/* ---- instances ----------------------------------------------------------------------- */

/* "file:///a%20b/resources/" -> "/a b/resources" (a new string). */
static char *local_path(const char *uri)
{
    if (strncmp(uri, "file://", 7) == 0) uri += 7;
    else if (strncmp(uri, "file:", 5) == 0) uri += 5;
    size_t n = strlen(uri);
    char *path = malloc(n + 1), *out = path;
    if (!path) return NULL;
    for (const char *p = uri; *p; p++) {
        unsigned int byte;
        if (p[0] == '%' && p[1] && p[2] && sscanf(p + 1, "%2x", &byte) == 1) {
            *out++ = (char)byte;
            p += 2;
        } else {
            *out++ = *p;
        }
    }
    while (out > path + 1 && out[-1] == '/') out--;
    *out = '\0';
    return path;
}

/* The first line of resources/slavemodule.txt, or NULL with a Python error set. */
static PyObject *module_name(const char *resources)
{
    char file[4096], line[512];
    snprintf(file, sizeof file, "%s/slavemodule.txt", resources);
    FILE *f = fopen(file, "r");
    if (!f) return PyErr_Format(PyExc_FileNotFoundError, "cannot open %s", file);
    char *ok = fgets(line, sizeof line, f);
    fclose(f);
    if (!ok) return PyErr_Format(PyExc_ValueError, "%s is empty", file);
    line[strcspn(line, " \t\r\n")] = '\0';
    return PyUnicode_FromString(line);
}

/* The one Fmi2Slave subclass defined in the FMU's script (a new reference), or NULL. */
static PyObject *find_slave_class(const char *resources)
{
    PyObject *cls = NULL, *sys_path = PySys_GetObject("path");   /* borrowed */
    PyObject *folder = PyUnicode_FromString(resources);
    if (!folder || !sys_path) goto done;
    int present = PySequence_Contains(sys_path, folder);
    if (present < 0 || (!present && PyList_Insert(sys_path, 0, folder) < 0)) goto done;

    PyObject *name = module_name(resources);
    PyObject *module = name ? PyImport_Import(name) : NULL;
    PyObject *pythonfmu = module ? PyImport_ImportModule("pythonfmu.fmi2slave") : NULL;
    PyObject *base = pythonfmu ? PyObject_GetAttrString(pythonfmu, "Fmi2Slave") : NULL;
    if (base) {
        /* a copy of the namespace (PyModule_GetDict's is borrowed: never released here), as
           the checks below run Python code */
        PyObject *dict = PyDict_Copy(PyModule_GetDict(module));
        PyObject *key, *value;
        Py_ssize_t pos = 0;
        int found = dict ? 0 : -1;
        while (dict && PyDict_Next(dict, &pos, &key, &value)) {
            int derived = (PyType_Check(value) && value != base)
                          ? PyObject_IsSubclass(value, base) : 0;
            if (derived < 0) { found = -1; break; }
            if (!derived) continue;
            PyObject *owner = PyObject_GetAttrString(value, "__module__");
            int here = owner ? PyObject_RichCompareBool(owner, name, Py_EQ) : -1;
            Py_XDECREF(owner);
            if (here < 0) { found = -1; break; }
            if (here) {
                found++;
                Py_XDECREF(cls);
                cls = Py_NewRef(value);
            }
        }
        if (found != 1) {
            Py_CLEAR(cls);
            if (found == 0)
                PyErr_Format(PyExc_TypeError, "module %S defines no subclass of Fmi2Slave", name);
            else if (found > 1)
                PyErr_Format(PyExc_TypeError, "module %S defines %d subclasses of Fmi2Slave, "
                             "an FMU script must define one", name, found);
        }
        Py_XDECREF(dict);
    }
    Py_XDECREF(base);
    Py_XDECREF(pythonfmu);
    Py_XDECREF(module);
    Py_XDECREF(name);
done:
    Py_XDECREF(folder);
    return cls;
}

/* Drop the slave. Its attributes are cleared first: a slave's variables hold getters and
   setters that refer back to it (a reference cycle), so without this a freed slave waits for a
   full collection of Python's cyclic garbage collector, which comes only when the older
   objects have grown by a quarter; until then every instantiate/free cycle added about a
   kilobyte (measured in tests/test_native.py). A full collection at each free would cost a
   few tens of milliseconds in a process with numpy, scipy and numba. */
static void release_slave(Instance *in)
{
    for (int m = 0; m < N_METHODS; m++) Py_CLEAR(in->methods[m]);
    Py_CLEAR(in->log_queue);
    Py_CLEAR(in->strings);
    if (in->slave) {
        PyObject *attributes = PyObject_GetAttrString(in->slave, "__dict__");
        if (attributes && PyDict_Check(attributes)) PyDict_Clear(attributes);
        Py_XDECREF(attributes);
        PyErr_Clear();   /* a slave without a __dict__ (slots) keeps its cycles, if any */
    }
    Py_CLEAR(in->slave);
}

/* A new slave object with its bound methods and log queue (pythonfmu's keyword arguments);
   -1 with a Python error set on failure. */
static int create_slave(Instance *in)
{
    release_slave(in);
    PyObject *args = PyTuple_New(0);
    PyObject *kwargs = Py_BuildValue("{s:s,s:s,s:n,s:O}", "instance_name", in->instance_name,
                                     "resources", in->resources,
                                     /* pythonfmu passes its logger's address; unused in Python */
                                     "logger", (Py_ssize_t)&in->functions,
                                     "visible", in->visible ? Py_True : Py_False);
    in->slave = (args && kwargs) ? PyObject_Call(in->slave_class, args, kwargs) : NULL;
    Py_XDECREF(args);
    Py_XDECREF(kwargs);
    if (!in->slave) return -1;
    for (int m = 0; m < N_METHODS; m++) {
        in->methods[m] = PyObject_GetAttrString(in->slave, METHOD_NAMES[m]);
        if (!in->methods[m]) return -1;
    }
    in->log_queue = PyObject_CallMethod(in->slave, "_get_log_queue", NULL);
    if (!in->log_queue) return -1;
    if (!PyList_Check(in->log_queue)) {
        Py_CLEAR(in->log_queue);
        PyErr_SetString(PyExc_TypeError, "_get_log_queue() must return a list");
        return -1;
    }
    return 0;
}

/* Whether the instance can take calls (not after a failed fmi2Reset: that one was logged). */
static int has_slave(const Instance *in)
{
    return in != NULL && in->slave != NULL;
}

static void free_instance_memory(Instance *in)
{
    for (size_t i = 0; i < in->n_categories; i++) free(in->categories[i]);
    free(in->categories);
    free(in->instance_name);
    free(in->resources);
    free(in);
}

FMI2_Export const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

FMI2_Export const char *fmi2GetVersion(void) { return fmi2Version; }

FMI2_Export fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType,
                                          fmi2String fmuGUID, fmi2String fmuResourceLocation,
                                          const fmi2CallbackFunctions *functions,
                                          fmi2Boolean visible, fmi2Boolean loggingOn)
{
    (void)fmuGUID;   /* pythonfmu's script does not know the GUID of its modelDescription */
    Instance *in = calloc(1, sizeof *in);
    if (!in) return NULL;
    if (functions) in->functions = *functions;
    in->instance_name = strdup(instanceName ? instanceName : "");
    in->visible = visible;
    in->logging_on = loggingOn;
    in->last_successful_time = 0.0;
    in->time_known = 1;
    if (!in->instance_name) { free_instance_memory(in); return NULL; }
    if (fmuType != fmi2CoSimulation || !fmuResourceLocation) {
        emit(in, fmi2Error, "logStatusError", fmuType != fmi2CoSimulation
             ? FMI_NAME(Instantiate) ": this FMU supports co-simulation only"
             : FMI_NAME(Instantiate) ": no resource location given");
        free_instance_memory(in);
        return NULL;
    }
    in->resources = local_path(fmuResourceLocation);
    if (!in->resources) { free_instance_memory(in); return NULL; }

    if (!Py_IsInitialized()) {
        /* A host without Python: start one and keep it until the process ends (see the top). */
        Py_InitializeEx(0);          /* 0: leave the host's signal handlers alone */
        PyEval_SaveThread();         /* release the GIL: each call takes it with PyGILState_Ensure */
    }
    PyGILState_STATE gil = PyGILState_Ensure();
    in->slave_class = find_slave_class(in->resources);
    if (!in->slave_class || create_slave(in) < 0) {
        report_exception(in, FMI_NAME(Instantiate));
        release_slave(in);
        Py_CLEAR(in->slave_class);
        PyGILState_Release(gil);
        free_instance_memory(in);
        return NULL;
    }
    flush_log(in);
    fmi2Component handle = register_instance(in);
    if (!handle) {
        emit(in, fmi2Error, "logStatusError", FMI_NAME(Instantiate) ": out of memory");
        release_slave(in);
        Py_CLEAR(in->slave_class);
    }
    PyGILState_Release(gil);
    if (!handle) free_instance_memory(in);
    return handle;
}

FMI2_Export void fmi2FreeInstance(fmi2Component c)
{
    if (!c) return;   /* as free(NULL): a host may free what fmi2Instantiate failed to make */
    Instance *in = unregister_instance(c, FMI_NAME(FreeInstance));
    if (!in) return;
    PyGILState_STATE gil = PyGILState_Ensure();
    release_slave(in);
    Py_CLEAR(in->slave_class);
    PyGILState_Release(gil);
    free_instance_memory(in);
}

FMI2_Export fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn,
                                           size_t nCategories, const fmi2String categories[])
{
    Instance *in = lookup(c, FMI_NAME(SetDebugLogging));
    if (!in) return fmi2Error;
    for (size_t i = 0; i < in->n_categories; i++) free(in->categories[i]);
    free(in->categories);
    in->categories = NULL;
    in->n_categories = 0;
    in->logging_on = loggingOn;
    if (nCategories > 0) {
        in->categories = calloc(nCategories, sizeof *in->categories);
        if (!in->categories) return fmi2Error;
        for (size_t i = 0; i < nCategories; i++) {
            in->categories[i] = strdup(categories[i] ? categories[i] : "");
            if (!in->categories[i]) return fmi2Error;
            in->n_categories = i + 1;
        }
    }
    return fmi2OK;
}

/* ---- calls into the slave ------------------------------------------------------------ */

/* How far a doStep's currentCommunicationPoint may be from the instance's time, relative to
   the larger of |time| and |step size|. The instance's time is the host's previous point plus
   its step (one rounded addition), so a host that forms its points as t0 + k h, accumulates
   t += h, or converts integer ticks to seconds differs from it by a few ulps (~1e-16
   relative); 1e-9 leaves six orders of magnitude for that, and stays below one step h until a
   run has 1e9 steps (a real wrong point is off by a step or more). */
#define TIME_TOLERANCE 1e-9

/* method(*args) on the slave, GIL taken here; fmi2OK or the exception as fmi2Error. */
static fmi2Status call(fmi2Component c, enum Method m, const char *function, const char *format,
                       ...)
{
    Instance *in = lookup(c, function);
    if (!has_slave(in)) return fmi2Error;
    PyGILState_STATE gil = PyGILState_Ensure();
    va_list va;
    va_start(va, format);
    PyObject *args = format ? Py_VaBuildValue(format, va) : PyTuple_New(0);
    va_end(va);
    PyObject *result = args ? PyObject_Call(in->methods[m], args, NULL) : NULL;
    Py_XDECREF(args);
    fmi2Status status = finish(in, function, result);
    PyGILState_Release(gil);
    return status;
}

static PyObject *optional(fmi2Boolean defined, fmi2Real value)
{
    return defined ? PyFloat_FromDouble(value) : Py_NewRef(Py_None);
}

FMI2_Export fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined,
                                           fmi2Real tolerance, fmi2Real startTime,
                                           fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    Instance *in = lookup(c, FMI_NAME(SetupExperiment));
    if (!has_slave(in)) return fmi2Error;
    in->last_successful_time = startTime;
    in->time_known = 1;
    PyGILState_STATE gil = PyGILState_Ensure();
    PyObject *stop = optional(stopTimeDefined, stopTime);
    PyObject *tol = optional(toleranceDefined, tolerance);
    PyObject *args = (stop && tol) ? Py_BuildValue("(dOO)", startTime, stop, tol) : NULL;
    PyObject *result = args ? PyObject_Call(in->methods[M_SETUP_EXPERIMENT], args, NULL) : NULL;
    Py_XDECREF(args);
    Py_XDECREF(stop);
    Py_XDECREF(tol);
    fmi2Status status = finish(in, FMI_NAME(SetupExperiment), result);
    PyGILState_Release(gil);
    return status;
}

FMI2_Export fmi2Status fmi2EnterInitializationMode(fmi2Component c)
{
    return call(c, M_ENTER_INITIALIZATION_MODE, FMI_NAME(EnterInitializationMode), NULL);
}

FMI2_Export fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    return call(c, M_EXIT_INITIALIZATION_MODE, FMI_NAME(ExitInitializationMode), NULL);
}

FMI2_Export fmi2Status fmi2Terminate(fmi2Component c)
{
    return call(c, M_TERMINATE, FMI_NAME(Terminate), NULL);
}

FMI2_Export fmi2Status fmi2Reset(fmi2Component c)
{
    Instance *in = lookup(c, FMI_NAME(Reset));
    if (!in) return fmi2Error;
    PyGILState_STATE gil = PyGILState_Ensure();
    flush_log(in);
    in->last_successful_time = 0.0;   /* until fmi2SetupExperiment says otherwise */
    in->time_known = 1;
    fmi2Status status = create_slave(in) < 0 ? report_exception(in, FMI_NAME(Reset)) : fmi2OK;
    PyGILState_Release(gil);
    return status;
}

FMI2_Export fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                                  fmi2Real communicationStepSize,
                                  fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    Instance *in = lookup(c, FMI_NAME(DoStep));
    if (!has_slave(in)) return fmi2Error;
    if (in->time_known) {
        double expected = in->last_successful_time;
        /* (a NaN step size gives |expected|: the slave then reports the bad step size) */
        double scale = fabs(communicationStepSize) > fabs(expected) ? fabs(communicationStepSize)
                                                                      : fabs(expected);
        double tolerance = TIME_TOLERANCE * scale;
        if (!(fabs(currentCommunicationPoint - expected) <= tolerance)) {   /* NaN too */
            char buffer[256];
            snprintf(buffer, sizeof buffer, FMI_NAME(DoStep) ": currentCommunicationPoint = %.17g s, "
                     "but the instance is at t = %.17g s (the end of its last step, or the "
                     "start time); the step is refused and the instance left as it was",
                     currentCommunicationPoint, expected);
            emit(in, fmi2Error, "logStatusError", buffer);
            return fmi2Error;
        }
    }
    PyGILState_STATE gil = PyGILState_Ensure();
    PyObject *t = PyFloat_FromDouble(currentCommunicationPoint);
    PyObject *h = PyFloat_FromDouble(communicationStepSize);
    PyObject *result = (t && h) ? PyObject_CallFunctionObjArgs(in->methods[M_DO_STEP], t, h, NULL)
                                : NULL;
    Py_XDECREF(t);
    Py_XDECREF(h);
    int done = result ? PyObject_IsTrue(result) : -1;
    Py_XDECREF(result);
    fmi2Status status;
    if (done < 0) {
        status = report_exception(in, FMI_NAME(DoStep));
    } else {
        flush_log(in);
        status = done ? fmi2OK : fmi2Discard;   /* do_step() returned False: as pythonfmu */
        in->last_successful_time = currentCommunicationPoint + (done ? communicationStepSize : 0.0);
        in->time_known = 1;
    }
    PyGILState_Release(gil);
    return status;
}

/* ---- values -------------------------------------------------------------------------- */

typedef PyObject *(*ToPython)(const void *values, size_t i);
typedef int (*FromPython)(Instance *in, PyObject *item, void *values, size_t i);

static PyObject *real_to_python(const void *v, size_t i) { return PyFloat_FromDouble(((const fmi2Real *)v)[i]); }
static PyObject *integer_to_python(const void *v, size_t i) { return PyLong_FromLong(((const fmi2Integer *)v)[i]); }
static PyObject *boolean_to_python(const void *v, size_t i) { return PyBool_FromLong(((const fmi2Boolean *)v)[i]); }
static PyObject *string_to_python(const void *v, size_t i)
{
    const char *s = ((const fmi2String *)v)[i];
    return PyUnicode_FromString(s ? s : "");
}

static int real_from_python(Instance *in, PyObject *item, void *v, size_t i)
{
    (void)in;
    double x = PyFloat_AsDouble(item);
    if (x == -1.0 && PyErr_Occurred()) return -1;
    ((fmi2Real *)v)[i] = x;
    return 0;
}

static int integer_from_python(Instance *in, PyObject *item, void *v, size_t i)
{
    (void)in;
    long x = PyLong_AsLong(item);
    if (x == -1 && PyErr_Occurred()) return -1;
    if (x < -2147483647L - 1 || x > 2147483647L) {
        PyErr_Format(PyExc_OverflowError, "value %ld does not fit an fmi2Integer", x);
        return -1;
    }
    ((fmi2Integer *)v)[i] = (fmi2Integer)x;
    return 0;
}

static int boolean_from_python(Instance *in, PyObject *item, void *v, size_t i)
{
    (void)in;
    int x = PyObject_IsTrue(item);
    if (x < 0) return -1;
    ((fmi2Boolean *)v)[i] = x ? fmi2True : fmi2False;
    return 0;
}

/* The pointer stays valid until the next fmi2GetString: in->strings holds the str objects. */
static int string_from_python(Instance *in, PyObject *item, void *v, size_t i)
{
    if (!PyUnicode_Check(item)) {
        PyErr_SetString(PyExc_TypeError, "get_string() must return str values");
        return -1;
    }
    if (PyList_Append(in->strings, item) < 0) return -1;
    const char *s = PyUnicode_AsUTF8AndSize(item, NULL);
    if (!s) return -1;
    ((fmi2String *)v)[i] = s;
    return 0;
}

static PyObject *references(const fmi2ValueReference vr[], size_t nvr)
{
    PyObject *list = PyList_New((Py_ssize_t)nvr);
    for (size_t i = 0; list && i < nvr; i++) {
        PyObject *x = PyLong_FromUnsignedLong(vr[i]);
        if (!x || PyList_SetItem(list, (Py_ssize_t)i, x) < 0) Py_CLEAR(list);
    }
    return list;
}

/* set_<type>([vr...], [value...]) */
static fmi2Status set_values(fmi2Component c, enum Method m, const char *function,
                             const fmi2ValueReference vr[], size_t nvr, const void *values,
                             ToPython convert)
{
    Instance *in = lookup(c, function);
    if (!has_slave(in)) return fmi2Error;
    PyGILState_STATE gil = PyGILState_Ensure();
    PyObject *refs = references(vr, nvr);
    PyObject *list = PyList_New((Py_ssize_t)nvr);
    for (size_t i = 0; list && i < nvr; i++) {
        PyObject *x = convert(values, i);
        if (!x || PyList_SetItem(list, (Py_ssize_t)i, x) < 0) Py_CLEAR(list);
    }
    PyObject *result = (refs && list)
        ? PyObject_CallFunctionObjArgs(in->methods[m], refs, list, NULL) : NULL;
    Py_XDECREF(refs);
    Py_XDECREF(list);
    fmi2Status status = finish(in, function, result);
    PyGILState_Release(gil);
    return status;
}

/* values[i] = get_<type>([vr...])[i] */
static fmi2Status get_values(fmi2Component c, enum Method m, const char *function,
                             const fmi2ValueReference vr[], size_t nvr, void *values,
                             FromPython convert)
{
    Instance *in = lookup(c, function);
    if (!has_slave(in)) return fmi2Error;
    PyGILState_STATE gil = PyGILState_Ensure();
    PyObject *refs = references(vr, nvr);
    PyObject *result = refs ? PyObject_CallFunctionObjArgs(in->methods[m], refs, NULL) : NULL;
    Py_XDECREF(refs);
    Py_ssize_t n = result ? PySequence_Size(result) : -1;
    if (n >= 0 && (size_t)n != nvr) {
        PyErr_Format(PyExc_ValueError, "%s returned %zd values for %zu value references",
                     METHOD_NAMES[m], n, nvr);
        n = -1;
    }
    for (Py_ssize_t i = 0; n >= 0 && i < n; i++) {
        PyObject *item = PySequence_GetItem(result, i);
        if (!item || convert(in, item, values, (size_t)i) < 0) n = -1;
        Py_XDECREF(item);
    }
    if (n < 0) Py_CLEAR(result);
    fmi2Status status = finish(in, function, result);
    PyGILState_Release(gil);
    return status;
}

FMI2_Export fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                   const fmi2Real value[])
{
    return set_values(c, M_SET_REAL, FMI_NAME(SetReal), vr, nvr, value, real_to_python);
}

FMI2_Export fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                      const fmi2Integer value[])
{
    return set_values(c, M_SET_INTEGER, FMI_NAME(SetInteger), vr, nvr, value, integer_to_python);
}

FMI2_Export fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                      const fmi2Boolean value[])
{
    return set_values(c, M_SET_BOOLEAN, FMI_NAME(SetBoolean), vr, nvr, value, boolean_to_python);
}

FMI2_Export fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                     const fmi2String value[])
{
    return set_values(c, M_SET_STRING, FMI_NAME(SetString), vr, nvr, value, string_to_python);
}

FMI2_Export fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                   fmi2Real value[])
{
    return get_values(c, M_GET_REAL, FMI_NAME(GetReal), vr, nvr, value, real_from_python);
}

FMI2_Export fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                      fmi2Integer value[])
{
    return get_values(c, M_GET_INTEGER, FMI_NAME(GetInteger), vr, nvr, value, integer_from_python);
}

FMI2_Export fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                      fmi2Boolean value[])
{
    return get_values(c, M_GET_BOOLEAN, FMI_NAME(GetBoolean), vr, nvr, value, boolean_from_python);
}

FMI2_Export fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                     fmi2String value[])
{
    Instance *in = lookup(c, FMI_NAME(GetString));
    if (!has_slave(in)) return fmi2Error;
    PyGILState_STATE gil = PyGILState_Ensure();
    Py_XDECREF(in->strings);                   /* the previous call's strings may go now */
    in->strings = PyList_New(0);
    int ok = in->strings != NULL;
    PyGILState_Release(gil);
    if (!ok) return fmi2Error;
    return get_values(c, M_GET_STRING, FMI_NAME(GetString), vr, nvr, (void *)value, string_from_python);
}

/* ---- FMU state (the slave's _get_fmu_state object; serialised by its class) --------- */

/* Hand the new state object `s` to the host in *state (which the caller has released). */
static fmi2Status give_state(Instance *in, const char *function, PyObject *s, fmi2FMUstate *state)
{
    if (!s) return report_exception(in, function);
    *state = s;
    flush_log(in);
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state)
{
    Instance *in = lookup(c, FMI_NAME(GetFMUstate));
    if (!has_slave(in) || !state) return fmi2Error;
    PyGILState_STATE gil = PyGILState_Ensure();
    PyObject *s = PyObject_CallNoArgs(in->methods[M_GET_FMU_STATE]);
    if (s) Py_CLEAR(*(PyObject **)state);   /* FMI: a state handed back in is overwritten */
    fmi2Status status = give_state(in, FMI_NAME(GetFMUstate), s, state);
    PyGILState_Release(gil);
    return status;
}

FMI2_Export fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state)
{
    if (!state) return fmi2Error;
    fmi2Status status = call(c, M_SET_FMU_STATE, FMI_NAME(SetFMUstate), "(O)", (PyObject *)state);
    /* The state's time is the slave's business (a serialised state carries no time of ours,
       and its bytes stay as they were): the next fmi2DoStep's time is taken as given. */
    Instance *in = status == fmi2OK ? lookup(c, FMI_NAME(SetFMUstate)) : NULL;
    if (in) in->time_known = 0;
    return status;
}

FMI2_Export fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state)
{
    (void)c;
    if (!state || !*state) return fmi2OK;
    PyGILState_STATE gil = PyGILState_Ensure();
    Py_CLEAR(*(PyObject **)state);
    PyGILState_Release(gil);
    return fmi2OK;
}

/* The serialised state as a new bytes object (GIL held), or NULL with an error set. */
static PyObject *state_bytes(Instance *in, fmi2FMUstate state)
{
    PyObject *b = PyObject_CallFunctionObjArgs(in->methods[M_STATE_TO_BYTES], (PyObject *)state, NULL);
    if (b && !PyBytes_Check(b)) {
        Py_CLEAR(b);
        PyErr_SetString(PyExc_TypeError, "_fmu_state_to_bytes() must return bytes");
    }
    return b;
}

FMI2_Export fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate state, size_t *size)
{
    Instance *in = lookup(c, FMI_NAME(SerializedFMUstateSize));
    if (!has_slave(in) || !state || !size) return fmi2Error;
    PyGILState_STATE gil = PyGILState_Ensure();
    PyObject *b = state_bytes(in, state);
    if (b) *size = (size_t)PyBytes_Size(b);
    fmi2Status status = finish(in, FMI_NAME(SerializedFMUstateSize), b);
    PyGILState_Release(gil);
    return status;
}

FMI2_Export fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate state,
                                             fmi2Byte serializedState[], size_t size)
{
    Instance *in = lookup(c, FMI_NAME(SerializeFMUstate));
    if (!has_slave(in) || !state) return fmi2Error;
    PyGILState_STATE gil = PyGILState_Ensure();
    PyObject *b = state_bytes(in, state);
    if (b && (size_t)PyBytes_Size(b) != size) {
        PyErr_Format(PyExc_ValueError, "the serialised state has %zd bytes, not %zu",
                     PyBytes_Size(b), size);
        Py_CLEAR(b);
    }
    if (b) memcpy(serializedState, PyBytes_AsString(b), size);
    fmi2Status status = finish(in, FMI_NAME(SerializeFMUstate), b);
    PyGILState_Release(gil);
    return status;
}

FMI2_Export fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[],
                                               size_t size, fmi2FMUstate *state)
{
    Instance *in = lookup(c, FMI_NAME(DeSerializeFMUstate));
    if (!has_slave(in) || !state) return fmi2Error;
    PyGILState_STATE gil = PyGILState_Ensure();
    PyObject *b = PyBytes_FromStringAndSize(serializedState, (Py_ssize_t)size);
    PyObject *s = b ? PyObject_CallFunctionObjArgs(in->methods[M_STATE_FROM_BYTES], b, NULL) : NULL;
    Py_XDECREF(b);
    fmi2Status status = give_state(in, FMI_NAME(DeSerializeFMUstate), s, state);
    PyGILState_Release(gil);
    return status;
}

/* ---- what the FMU does not support (its modelDescription says so) -------------------- */

static fmi2Status unsupported(fmi2Component c, const char *function)
{
    Instance *in = lookup(c, function);
    if (!in) return fmi2Error;
    char buffer[160];
    snprintf(buffer, sizeof buffer, "%s: not supported by this FMU", function);
    emit(in, fmi2Error, "logStatusError", buffer);
    return fmi2Error;
}

FMI2_Export fmi2Status fmi2GetDirectionalDerivative(fmi2Component c,
        const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
        const fmi2ValueReference vKnown_ref[], size_t nKnown,
        const fmi2Real dvKnown[], fmi2Real dvUnknown[])
{
    (void)vUnknown_ref; (void)nUnknown; (void)vKnown_ref; (void)nKnown; (void)dvKnown; (void)dvUnknown;
    return unsupported(c, FMI_NAME(GetDirectionalDerivative));
}

FMI2_Export fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
        size_t nvr, const fmi2Integer order[], const fmi2Real value[])
{
    (void)vr; (void)nvr; (void)order; (void)value;
    return unsupported(c, FMI_NAME(SetRealInputDerivatives));
}

FMI2_Export fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
        size_t nvr, const fmi2Integer order[], fmi2Real value[])
{
    (void)vr; (void)nvr; (void)order; (void)value;
    return unsupported(c, FMI_NAME(GetRealOutputDerivatives));
}

FMI2_Export fmi2Status fmi2CancelStep(fmi2Component c)
{
    return unsupported(c, FMI_NAME(CancelStep));   /* doStep never returns fmi2Pending */
}

/* Status inquiries: only the last successful time exists (doStep is synchronous). */
FMI2_Export fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value)
{
    (void)s; (void)value;
    return lookup(c, FMI_NAME(GetStatus)) ? fmi2Discard : fmi2Error;
}

FMI2_Export fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value)
{
    Instance *in = lookup(c, FMI_NAME(GetRealStatus));
    if (!in || !value) return fmi2Error;
    if (s != fmi2LastSuccessfulTime) return fmi2Discard;
    *value = in->last_successful_time;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value)
{
    (void)s; (void)value;
    return lookup(c, FMI_NAME(GetIntegerStatus)) ? fmi2Discard : fmi2Error;
}

FMI2_Export fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value)
{
    (void)s; (void)value;
    return lookup(c, FMI_NAME(GetBooleanStatus)) ? fmi2Discard : fmi2Error;
}

FMI2_Export fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value)
{
    (void)s; (void)value;
    return lookup(c, FMI_NAME(GetStringStatus)) ? fmi2Discard : fmi2Error;
}
