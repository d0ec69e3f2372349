/* tendonkit model runtime: one generic evaluator for every exported tendonkit model.
 *
 * The model is not compiled into this code: `tk_load` reads it from the FMU's resource
 * `model.tkm` (a flat array of little-endian float64 written by tendonkit.fmu.cfmu), so one
 * binary per platform serves every model and exporting needs no compiler.  The evaluation
 * follows tendonkit.stepper.Stepper (the Python reference) operation by operation:
 * input blocks, the representation (state space, ARX, sparse map, with nonlinear terms),
 * output blocks, then the constant-ratio joint reconstruction and the forward kinematics.
 *
 * All mutable state lives in one array of doubles (`tk_model.S`), so an FMU state is a copy
 * of it and its serialisation is its bytes.
 */
#ifndef TENDONKIT_RUNTIME_H
#define TENDONKIT_RUNTIME_H

#include <stddef.h>

/* Portable helpers: the Windows build links msvcrt.dll only (no mingw runtime), so it uses
 * msvcrt's _snprintf/_vsnprintf, and finiteness is tested without libm's classification. */
#if defined(_WIN32)
#define TK_SNPRINTF _snprintf
#define TK_VSNPRINTF _vsnprintf
#else
#define TK_SNPRINTF snprintf
#define TK_VSNPRINTF vsnprintf
#endif
#define TK_FINITE(x) ((x) - (x) == 0.0)

#define TK_FORMAT 5.0
#define TK_MAGIC 7318.2026 /* first number of every model.tkm */

typedef struct {
    int sig, kind;   /* signal index; 0 delay, 1 dead_zone, 2 saturation, 3 play, 4 lag, 5 rate, 6 polynomial, 7 second-order section */
    double p0, p1;   /* parameters (delay: whole samples n and fraction a; polynomial: c0, c1) */
    double p2, p3;   /* polynomial: c2, c3; second-order section: a1, a2 (p0, p1: b1, b2) */
    double g;        /* second-order section: static gain (1 + b1 + b2) / (1 + a1 + a2) */
    int n;           /* delay: whole samples */
    int off;         /* offset of this block's state in S: started, v, s0, head, fifo[n + 1] */
} tk_block;

typedef struct {
    /* ---- the model (read-only after tk_load) */
    int rep;                 /* 0 state space, 1 ARX, 2 sparse map */
    int nu, ny, nx, nt, nf;  /* inputs, outputs, states, terms, factors */
    double dt;
    int lag, H;              /* padding length of the histories and their capacity (lag + 1) */
    int nbi, nbo;
    tk_block *bi, *bo;
    double *A, *B, *C, *D, *E, *x0;  /* state space (E: n x nt); x0 also for the sparse map */
    int nl, na;
    double *G, *Acat, *off, *coef_t; /* ARX: G (nl, ny, nu), Acat (ny, na ny), coef_t (ny, nt) */
    int *Gused;
    double *coef;            /* sparse map: (nt, nx) */
    int *outst;              /* sparse map: output states */
    int *ptr, *src, *col, *flag, *fdiff, *src2, *col2, *code; /* src2 -1: no minus */
    double *power, *scale, *offset, *param, *param2, *weight;
    int kin, iq1, iq2;
    double ratio0[4], R[6], pitch, tool;
    double *u0;              /* input start values (the operating point) */
    int nout;                /* ny (+ 7 with the kinematics) */
    /* ---- the state: everything that changes, in one array */
    int ns;
    double *S;
    int s_x, s_uh, s_yh, s_xh, s_blk, s_u, s_ratio;
    int s_fs;                /* two numbers per factor: a hysteresis operator's state */
    /* ---- work arrays */
    double *ub, *yraw, *theta, *xn;
    double *store;           /* one allocation for everything above */
} tk_model;

/* S[0..3]: time index, dead flag, history count, history head */
#define TK_TIME_INDEX 0
#define TK_DEAD 1
#define TK_COUNT 2
#define TK_HEAD 3
#define TK_HEADER 4

/* Read `path` into `m`; on failure return non-zero with a message in `why`. */
int tk_load(tk_model *m, const char *path, char *why, size_t nwhy);
void tk_free(tk_model *m);
/* Back to the model's initial state, inputs at their start values, ratios at theirs. */
void tk_reset(tk_model *m);
/* Whether S (ns doubles) is a state this model can continue from (indices in range). */
int tk_state_ok(const tk_model *m, const double *S);
/* Outputs (nout) for the current state and inputs S[s_u..]; may mark the state diverged. */
void tk_outputs(tk_model *m, double *out);
/* Commit the current inputs and move one sample on; returns 0, or 1 once diverged. */
int tk_advance(tk_model *m);

#endif
