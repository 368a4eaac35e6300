/* The paper's reference interval (eq. 11) in one pass over the agents: fxc_env.engine._reference_kernel.
 *
 * A compiled kernel for ConsensusEngine.step_reference where the agents observe exactly
 * (fxc_env/engine/reference.py). Per agent i it gathers the in-neighbours' [x_j, v_j], forms
 * the neighbour sums S = sum_j (z_j - z_i) slot by slot, the plan a_x = (S_x + T S_v) / (d_i + 1),
 * a_v = S_v / (d_i + 1), the minimum-energy affine input's ends u0, u1 (fxc_env/core/dynamics.py,
 * input_from_plan), the exact double-integrator step, the input's energy and peak, and for
 * dim = 1 the running extremes of x and v (the disagreement's ranges). numpy's path makes the
 * same values in some twenty passes over the agents; this makes them in one, while the gathered
 * rows are in the cache.
 *
 * Every operation is the numpy path's, in its order, in IEEE double arithmetic: built without
 * contracting a * b + c into a fused multiply-add (-ffp-contract=off, pyproject.toml), the
 * results are bit for bit numpy's (tests/engine/test_reference_fast_path.py). The ranges turn
 * NaN once any new state is not finite (x - x is summed in), so such a step is refused as on numpy.
 *
 * Arrays (C-contiguous; checked by size here, float64 by reference.exact_observations):
 *   state   (N, 2, dim) float64  [x | v] per agent at t_k
 *   index   (N, slots)  int64    in-neighbour of every slot, padded slots the agent itself
 *   weight  (N,)        float64  1 / (d_i + 1)
 * Outputs: plans (N, 2 dim); or the state at t_{k+1} (N, 2, dim), u0 and u1 (N, dim), energy
 * and peak (N,) and the ranges [e_x, e_v] (2,).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <string.h>
#include <stdint.h>

/* Agents ahead whose neighbours' rows are fetched early: the gather is the pass's cost. */
#define PREFETCH_AHEAD 16

typedef struct {
    Py_buffer state, index, weight;
    Py_ssize_t n, slots, dim;
} Inputs;

static void release(Inputs *in) {
    PyBuffer_Release(&in->state);
    PyBuffer_Release(&in->index);
    PyBuffer_Release(&in->weight);
}

/* Largest dim (fxc_env.core.validation.MAX_DIM): the sums of one agent live on the stack. */
#define MAX_DIM 1024

/* S = sum_j (z_j - z_i) over the slots of one agent, every entry of the row [x | v] (2 dim), slot by slot. */
static inline __attribute__((always_inline)) void neighbour_sums(const double *state, const int64_t *neighbours,
                                                                 Py_ssize_t slots, const Py_ssize_t row,
                                                                 const double *own, double *sums) {
    const double *first = state + neighbours[0] * row;
    for (Py_ssize_t k = 0; k < row; k++) sums[k] = first[k] - own[k];
    for (Py_ssize_t s = 1; s < slots; s++) {
        const double *other = state + neighbours[s] * row;
        for (Py_ssize_t k = 0; k < row; k++) sums[k] += other[k] - own[k];
    }
}

static inline void prefetch(const double *state, const int64_t *index, Py_ssize_t i, Py_ssize_t n,
                            Py_ssize_t slots, Py_ssize_t row) {
    if (i + PREFETCH_AHEAD < n) {
        const int64_t *ahead = index + (i + PREFETCH_AHEAD) * slots;
        for (Py_ssize_t s = 0; s < slots; s++) __builtin_prefetch(state + ahead[s] * row);
    }
}

/* Parse (state, index, weight, n, dim, T): the inputs and their sizes checked against N and dim. */
static int parse_inputs(PyObject *args, Inputs *in, double *T, Py_buffer *outputs, const char *format,
                        int n_outputs) {
    memset(in, 0, sizeof(*in));
    int ok;
    if (n_outputs == 1) {
        ok = PyArg_ParseTuple(args, format, &in->state, &in->index, &in->weight, &in->n, &in->dim, T, &outputs[0]);
    } else {
        ok = PyArg_ParseTuple(args, format, &in->state, &in->index, &in->weight, &in->n, &in->dim, T, &outputs[0],
                              &outputs[1], &outputs[2], &outputs[3], &outputs[4], &outputs[5]);
    }
    if (!ok) return -1;
    const Py_ssize_t f = (Py_ssize_t)sizeof(double);
    if (in->n < 1 || in->dim < 1 || in->dim > MAX_DIM || in->state.len != in->n * 2 * in->dim * f ||
        in->weight.len != in->n * f || in->index.len == 0 ||
        in->index.len % (in->n * (Py_ssize_t)sizeof(int64_t)) != 0) {
        PyErr_SetString(PyExc_ValueError, "state, index, weight: sizes do not match N, dim and at least one slot");
        release(in);
        for (int k = 0; k < n_outputs; k++) PyBuffer_Release(&outputs[k]);
        return -1;
    }
    in->slots = in->index.len / (in->n * (Py_ssize_t)sizeof(int64_t));
    return 0;
}

static PyObject *plans(PyObject *self, PyObject *args) {
    Inputs in;
    double T;
    Py_buffer out[1];
    if (parse_inputs(args, &in, &T, out, "y*y*y*nndw*", 1) < 0) return NULL;
    if (out[0].len != in.state.len) {
        PyErr_SetString(PyExc_ValueError, "plans: expected (N, 2 dim) float64");
        release(&in);
        PyBuffer_Release(&out[0]);
        return NULL;
    }
    const double *state = in.state.buf, *weight = in.weight.buf;
    const int64_t *index = in.index.buf;
    double *plans_out = out[0].buf;
    const Py_ssize_t n = in.n, dim = in.dim, slots = in.slots, row = 2 * dim;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t i = 0; i < n; i++) {
        prefetch(state, index, i, n, slots, row);
        double *sums = plans_out + i * row;
        neighbour_sums(state, index + i * slots, slots, row, state + i * row, sums);
        for (Py_ssize_t c = 0; c < dim; c++) {
            sums[c] += sums[dim + c] * T;  /* a_x = (S_x + T S_v) / (d_i + 1), a_v = S_v / (d_i + 1) */
            sums[c] *= weight[i], sums[dim + c] *= weight[i];
        }
    }
    Py_END_ALLOW_THREADS
    release(&in);
    PyBuffer_Release(&out[0]);
    Py_RETURN_NONE;
}

/* The interval's outputs: the new state, the input's ends, energy and peak; the ranges for dim = 1. */
typedef struct {
    double *next, *u0, *u1, *energy, *peak, *ranges;
} Outputs;

/* One pass over the agents; inlined with dim = 1, 2 and 3 constants (line, plane, space) and once for any dim. */
static inline __attribute__((always_inline)) void play(const double *state, const int64_t *index,
                                                       const double *weight, Py_ssize_t n, Py_ssize_t slots,
                                                       const Py_ssize_t dim, double T, Outputs out) {
    const Py_ssize_t row = 2 * dim;
    /* input_from_plan's and interval_increments' coefficients, formed as they are in Python */
    const double inv_t = 1.0 / T, position_gain = 6.0 * inv_t * inv_t, velocity_gain = 2.0 * inv_t;
    const double half_square = T * T / 6.0, half = 0.5 * T, third = T / 3.0;
    /* extremes by plain comparisons (minsd / maxsd), with x - x summed in: NaN once any x is not finite */
    double low_x = INFINITY, high_x = -INFINITY, low_v = INFINITY, high_v = -INFINITY, not_finite = 0.0;
    for (Py_ssize_t i = 0; i < n; i++) {
        prefetch(state, index, i, n, slots, row);
        const double *own = state + i * row;
        double agent_energy = 0.0, agent_peak = 0.0, sums[2 * MAX_DIM];
        neighbour_sums(state, index + i * slots, slots, row, own, sums);
        for (Py_ssize_t c = 0; c < dim; c++) {
            const double a_x = (sums[c] + sums[dim + c] * T) * weight[i], a_v = sums[dim + c] * weight[i];
            const double position_term = position_gain * a_x, velocity_term = velocity_gain * a_v;
            const double start = position_term - velocity_term, end = 2.0 * velocity_term - position_term;
            const double total = start + end, v = own[dim + c];
            const double x_next = own[c] + (T * v + half_square * (start + total));
            const double v_next = v + half * total;
            /* a NaN input makes the energy NaN, which refuses the step: the peak needs no NaN rule */
            const double component_energy = (start * total + end * end) * third;
            const double magnitude = fabs(start) > fabs(end) ? fabs(start) : fabs(end);
            out.next[i * row + c] = x_next;
            out.next[i * row + dim + c] = v_next;
            out.u0[i * dim + c] = start;
            out.u1[i * dim + c] = end;
            if (c == 0) {
                agent_energy = component_energy, agent_peak = magnitude;
            } else {
                agent_energy += component_energy, agent_peak = magnitude > agent_peak ? magnitude : agent_peak;
            }
            if (dim == 1) {
                low_x = x_next < low_x ? x_next : low_x, high_x = x_next > high_x ? x_next : high_x;
                low_v = v_next < low_v ? v_next : low_v, high_v = v_next > high_v ? v_next : high_v;
                not_finite += (x_next - x_next) + (v_next - v_next);
            }
        }
        out.energy[i] = agent_energy;
        out.peak[i] = agent_peak;
    }
    out.ranges[0] = (high_x - low_x) + not_finite;
    out.ranges[1] = (high_v - low_v) + not_finite;
}

static PyObject *interval(PyObject *self, PyObject *args) {
    Inputs in;
    double T;
    Py_buffer out[6]; /* state, u0, u1, energy, peak, ranges */
    if (parse_inputs(args, &in, &T, out, "y*y*y*nndw*w*w*w*w*w*", 6) < 0) return NULL;
    const Py_ssize_t f = (Py_ssize_t)sizeof(double), n = in.n, dim = in.dim;
    if (out[0].len != in.state.len || out[1].len != n * dim * f || out[2].len != n * dim * f ||
        out[3].len != n * f || out[4].len != n * f || out[5].len != 2 * f) {
        PyErr_SetString(PyExc_ValueError, "interval: outputs expected (N, 2, dim), (N, dim) twice, (N,) twice, (2,)");
        release(&in);
        for (int k = 0; k < 6; k++) PyBuffer_Release(&out[k]);
        return NULL;
    }
    Outputs outputs = {out[0].buf, out[1].buf, out[2].buf, out[3].buf, out[4].buf, out[5].buf};
    Py_BEGIN_ALLOW_THREADS
    if (dim == 1) {
        play(in.state.buf, in.index.buf, in.weight.buf, n, in.slots, 1, T, outputs);
    } else if (dim == 2) {
        play(in.state.buf, in.index.buf, in.weight.buf, n, in.slots, 2, T, outputs);
    } else if (dim == 3) {
        play(in.state.buf, in.index.buf, in.weight.buf, n, in.slots, 3, T, outputs);
    } else {
        play(in.state.buf, in.index.buf, in.weight.buf, n, in.slots, dim, T, outputs);
    }
    Py_END_ALLOW_THREADS
    release(&in);
    for (int k = 0; k < 6; k++) PyBuffer_Release(&out[k]);
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"plans", plans, METH_VARARGS,
     "plans(state, index, weight, n, dim, T, out): the reference's plans [a_x | a_v] (N, 2 dim) into out."},
    {"interval", interval, METH_VARARGS,
     "interval(state, index, weight, n, dim, T, next, u0, u1, energy, peak, ranges): one reference interval."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_reference_kernel",
                                    "The reference interval (paper eq. 11) in one compiled pass.", -1, methods};

PyMODINIT_FUNC PyInit__reference_kernel(void) { return PyModule_Create(&module); }
