/* The master's stepping loop in C (orchestration/master.py, _python_steps is the reference).
 *
 * cosim_steps() runs the base steps k0 .. k1-1 of a co-simulation whose FMUs are already
 * initialised, following the tables of its schedule (orchestration/schedule.py: which
 * components are due at k, in Gauss-Seidel order; which buffer slots each one's inputs are
 * gathered from): per base step k, the components due at k each get one fmi2SetReal of their
 * inputs from the shared value buffer, one fmi2DoStep(k h, step) and one fmi2GetReal of their
 * outputs straight into the buffer; then one NaN check of the connected outputs, and a
 * recorded row (t, values[record_idx]) every `every` base steps. It returns early on an FMI
 * status above fmi2Warning or a NaN, saying where, so that Python raises the same RunError as
 * its own loop and keeps the rows written before.
 *
 * No FMI header is needed: the three function types are those of fmi2FunctionTypes.h (FMI 2.0),
 * called through pointers the caller took from each FMU's library. Plain C99; compiled without
 * -ffast-math (the NaN test x != x must stay).
 */
#include <stddef.h>
#include <stdint.h>

typedef void *fmi2Component;
typedef unsigned int fmi2ValueReference;
typedef int fmi2Status;                   /* 0 OK, 1 Warning, 2 Discard, 3 Error, 4 Fatal, 5 Pending */
typedef fmi2Status SetReal(fmi2Component, const fmi2ValueReference[], size_t, const double[]);
typedef fmi2Status GetReal(fmi2Component, const fmi2ValueReference[], size_t, double[]);
typedef fmi2Status DoStep(fmi2Component, double, double, int);

typedef struct {                          /* one component (master.py's _Slot) */
    SetReal *set_real;
    DoStep *do_step;
    GetReal *get_real;
    fmi2Component component;
    size_t n_in;                          /* inputs: in_buf[i] = values[in_idx[i]] */
    const fmi2ValueReference *in_vr;
    const int64_t *in_idx;
    double *in_buf;
    size_t n_out;                         /* outputs into values[out_start ..] */
    const fmi2ValueReference *out_vr;
    int64_t out_start;
    int64_t n_check;                      /* the first n_check outputs are connected */
    double step;                          /* communication step size */
} Slot;

typedef struct {
    const Slot *slots;
    int64_t n_slots;
    const int64_t *due;                   /* due at base step k: slots due[due_start[j]] .. */
    const int64_t *due_start;             /* .. due[due_start[j + 1] - 1], j the row of k: */
    int64_t period;                       /* k % period before tail_start, then */
    int64_t tail_start;                   /* period + k - tail_start (Schedule.row) */
    double *values;                       /* the shared value buffer */
    const int64_t *record_idx;
    int64_t n_record;
    int64_t every;                        /* record every `every` base steps */
    double h;                             /* base step */
} Loop;

enum { RAN = -1, SET_REAL = 0, DO_STEP = 1, GET_REAL = 2, NAN_OUTPUT = 3 };

typedef struct {                          /* where the loop stopped early (function RAN: it did not) */
    int64_t k;
    int64_t slot;
    int32_t function;
    int32_t status;
} Stop;

static int connected_nan(const Loop *loop)
{
    for (int64_t i = 0; i < loop->n_slots; i++) {
        const double *v = loop->values + loop->slots[i].out_start;
        for (int64_t j = 0; j < loop->slots[i].n_check; j++)
            if (v[j] != v[j]) return 1;
    }
    return 0;
}

/* Run base steps k0 .. k1-1; rows (row-major, 1 + n_record per row) gets the recorded rows.
 * Returns how many rows were written; *stop says whether and where it stopped early. */
int64_t cosim_steps(const Loop *loop, int64_t k0, int64_t k1, double *rows, Stop *stop)
{
    double *values = loop->values;
    int64_t n_rows = 0;
    stop->function = RAN;
    for (int64_t k = k0; k < k1; k++) {
        const double t = (double)k * loop->h;
        const int64_t j = k < loop->tail_start ? k % loop->period : loop->period + k - loop->tail_start;
        for (int64_t d = loop->due_start[j]; d < loop->due_start[j + 1]; d++) {
            const Slot *s = &loop->slots[loop->due[d]];
            int32_t function = SET_REAL;
            fmi2Status status = 0;
            if (s->n_in) {
                for (size_t i = 0; i < s->n_in; i++) s->in_buf[i] = values[s->in_idx[i]];
                status = s->set_real(s->component, s->in_vr, s->n_in, s->in_buf);
            }
            if (status <= 1) {
                function = DO_STEP;
                status = s->do_step(s->component, t, s->step, 1);  /* noSetFMUStatePriorToCurrentPoint */
            }
            if (status <= 1 && s->n_out) {
                function = GET_REAL;
                status = s->get_real(s->component, s->out_vr, s->n_out, values + s->out_start);
            }
            if (status > 1) {             /* above fmi2Warning */
                stop->k = k;
                stop->slot = loop->due[d];
                stop->function = function;
                stop->status = status;
                return n_rows;
            }
        }
        if (connected_nan(loop)) {
            stop->k = k;
            stop->slot = -1;
            stop->function = NAN_OUTPUT;
            stop->status = 0;
            return n_rows;
        }
        if ((k + 1) % loop->every == 0) {
            double *row = rows + n_rows * (1 + loop->n_record);
            row[0] = (double)(k + 1) * loop->h;
            for (int64_t i = 0; i < loop->n_record; i++) row[1 + i] = values[loop->record_idx[i]];
            n_rows++;
        }
    }
    return n_rows;
}
