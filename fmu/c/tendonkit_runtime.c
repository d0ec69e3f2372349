/* tendonkit model runtime (see tendonkit_runtime.h). */
#include "tendonkit_runtime.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Python's max(a, b) and min(a, b): the first argument unless the second is strictly
 * beyond it (NaN handling as in the reference, unlike fmax/fmin). */
static double pmax(double a, double b) { return b > a ? b : a; }
static double pmin(double a, double b) { return b < a ? b : a; }
/* numpy's sign: NaN stays NaN. */
static double nsign(double z) { return z > 0.0 ? 1.0 : (z < 0.0 ? -1.0 : (z == 0.0 ? 0.0 : z)); }

/* ------------------------------------------------------------------ reading the resource */

typedef struct {
    const double *v;
    size_t n, i;
    int bad;
} reader;

static double next(reader *r) {
    if (r->i >= r->n) {
        r->bad = 1;
        return 0.0;
    }
    return r->v[r->i++];
}

static int next_int(reader *r, int lo, int hi) {
    double x = next(r);
    if (!(x >= lo && x <= hi) || x != floor(x)) {
        r->bad = 1;
        return lo;
    }
    return (int)x;
}

static void next_array(reader *r, double *dst, size_t n) {
    size_t k;
    for (k = 0; k < n; k++) dst[k] = next(r);
}

static int load_blocks(reader *r, tk_block *b, int nb, int nsig) {
    int k;
    for (k = 0; k < nb; k++) {
        b[k].sig = next_int(r, 0, nsig - 1);
        b[k].kind = next_int(r, 0, 7);
        b[k].p0 = next(r);
        b[k].p1 = next(r);
        b[k].p2 = next(r); /* a cubic's c2, c3 (0 for the other kinds) */
        b[k].p3 = next(r);
        b[k].n = 0;
        b[k].g = b[k].kind == 7 ? (1.0 + b[k].p0 + b[k].p1) / (1.0 + b[k].p2 + b[k].p3) : 1.0;
        if (b[k].kind == 0) {
            if (!(b[k].p0 >= 0 && b[k].p0 <= 100000 && b[k].p0 == floor(b[k].p0))) r->bad = 1;
            else b[k].n = (int)b[k].p0;
        }
    }
    return !r->bad;
}

#define LIMIT 100000 /* bound on every count and lag read from a resource */
#define MAX_VALUES 5e7 /* bound on the numbers a model and its state hold (400 MB) */

/* Whether a factor's column c of buffer src exists (ARX: inputs or outputs; state space:
 * inputs or outputs; sparse map: states or inputs) and an ARX output is read at lag >= 1. */
static int column_ok(const tk_model *m, int src, int c, int lag) {
    int ncols;
    if (m->rep == 2) ncols = src == 0 ? m->nx : m->nu;
    else ncols = src == 0 ? m->nu : m->ny;
    return c < ncols && !(m->rep == 1 && src == 1 && lag < 1);
}

int tk_load(tk_model *m, const char *path, char *why, size_t nwhy) {
    FILE *f;
    long size;
    double *raw;
    reader r;
    int k, nt1, nbi_state, i;
    size_t need, pos;
    tk_block *blocks;

    memset(m, 0, sizeof(*m));
    f = fopen(path, "rb");
    if (!f) {
        TK_SNPRINTF(why, nwhy, "cannot open the model resource %s", path);
        return 1;
    }
    fseek(f, 0, SEEK_END);
    size = ftell(f);
    fseek(f, 0, SEEK_SET);
    if (size <= 0 || size % 8 != 0 || size > 512L * 1024 * 1024) {
        fclose(f);
        TK_SNPRINTF(why, nwhy, "the model resource %s is not a tendonkit model (size %ld)", path, size);
        return 1;
    }
    raw = (double *)malloc((size_t)size);
    if (!raw || fread(raw, 1, (size_t)size, f) != (size_t)size) {
        fclose(f);
        free(raw);
        TK_SNPRINTF(why, nwhy, "cannot read the model resource %s", path);
        return 1;
    }
    fclose(f);
    r.v = raw;
    r.n = (size_t)size / 8;
    r.i = 0;
    r.bad = 0;
    if (next(&r) != TK_MAGIC || next(&r) != TK_FORMAT) {
        free(raw);
        TK_SNPRINTF(why, nwhy, "the model resource %s is not a tendonkit model of format %g", path,
                 TK_FORMAT);
        return 1;
    }
    m->rep = next_int(&r, 0, 2);
    m->nu = next_int(&r, 1, LIMIT);
    m->ny = next_int(&r, 1, LIMIT);
    m->nx = next_int(&r, 0, LIMIT);
    m->nt = next_int(&r, 0, LIMIT);
    m->nf = next_int(&r, 0, LIMIT);
    m->dt = next(&r);
    m->lag = next_int(&r, 0, LIMIT);
    m->H = m->lag + 1;
    m->kin = next_int(&r, 0, 1);
    m->iq1 = next_int(&r, 0, m->ny - 1);
    m->iq2 = next_int(&r, 0, m->ny - 1);
    next_array(&r, m->ratio0, 4);
    next_array(&r, m->R, 6);
    m->pitch = next(&r);
    m->tool = next(&r);
    if (r.bad) goto bad;
    m->nout = m->ny + (m->kin ? 7 : 0);
    nt1 = m->nt + 1;

    /* sizes first: one allocation holds every array */
    pos = r.i + (size_t)m->nu; /* u0 */
    if (pos >= r.n || !(raw[pos] >= 0 && raw[pos] <= LIMIT)) goto bad;
    m->nbi = (int)raw[pos];
    pos += 1 + 6 * (size_t)m->nbi;
    if (pos >= r.n || !(raw[pos] >= 0 && raw[pos] <= LIMIT)) goto bad;
    m->nbo = (int)raw[pos];
    /* every array below must be far from int and memory limits: a resource asking for more
     * is corrupt (this also keeps the int offsets of the state layout from overflowing) */
    if ((double)m->H * (m->nu + m->ny + m->nx) + (double)m->nx * (m->nx + m->nu + m->nt) +
            (double)m->ny * (m->nx + m->nu) + 15.0 * m->nf + (double)m->nt * (m->ny + 1) >
        MAX_VALUES)
        goto bad;

    need = (size_t)m->nu                       /* u0 */
           + (size_t)m->nx * m->nx + (size_t)m->nx * m->nu + (size_t)m->ny * m->nx
           + (size_t)m->ny * m->nu + (size_t)m->nx + (size_t)m->nx * m->nt /* A B C D x0 E */
           + (size_t)m->nt * m->nx                                       /* coef */
           + 6 * (size_t)m->nf                                          /* power..weight */
           + (size_t)m->nu + (size_t)m->ny + (size_t)m->nt + (size_t)m->nx; /* ub yraw theta xn */
    m->store = (double *)calloc(need + 1, sizeof(double));
    m->bi = (tk_block *)calloc((size_t)m->nbi + 1, sizeof(tk_block));
    m->bo = (tk_block *)calloc((size_t)m->nbo + 1, sizeof(tk_block));
    m->ptr = (int *)calloc((size_t)nt1 + 7 * (size_t)m->nf + (size_t)m->ny + 1, sizeof(int));
    if (!m->store || !m->bi || !m->bo || !m->ptr) {
        free(raw);
        tk_free(m);
        TK_SNPRINTF(why, nwhy, "out of memory reading %s", path);
        return 1;
    }
    {
        double *p = m->store;
        m->u0 = p; p += m->nu;
        m->A = p; p += (size_t)m->nx * m->nx;
        m->B = p; p += (size_t)m->nx * m->nu;
        m->C = p; p += (size_t)m->ny * m->nx;
        m->D = p; p += (size_t)m->ny * m->nu;
        m->x0 = p; p += m->nx;
        m->E = p; p += (size_t)m->nx * m->nt;
        m->coef = p; p += (size_t)m->nt * m->nx;
        m->power = p; p += m->nf;
        m->scale = p; p += m->nf;
        m->offset = p; p += m->nf;
        m->param = p; p += m->nf;
        m->param2 = p; p += m->nf;
        m->weight = p; p += m->nf;
        m->ub = p; p += m->nu;
        m->yraw = p; p += m->ny;
        m->theta = p; p += m->nt;
        m->xn = p; p += m->nx;
        (void)p;
    }
    {
        int *q = m->ptr + nt1;
        m->src = q; q += m->nf;
        m->col = q; q += m->nf;
        m->flag = q; q += m->nf;
        m->fdiff = q; q += m->nf;
        m->src2 = q; q += m->nf;
        m->col2 = q; q += m->nf;
        m->code = q; q += m->nf;
        m->outst = q;
    }
    next_array(&r, m->u0, (size_t)m->nu);
    next(&r); /* nbi */
    load_blocks(&r, m->bi, m->nbi, m->nu);
    next(&r); /* nbo */
    load_blocks(&r, m->bo, m->nbo, m->ny);
    for (k = 0; k < nt1; k++) m->ptr[k] = next_int(&r, 0, m->nf);
    if (!r.bad && (m->ptr[0] != 0 || m->ptr[m->nt] != m->nf)) r.bad = 1;
    for (k = 0; k < m->nt && !r.bad; k++)
        if (m->ptr[k + 1] < m->ptr[k]) r.bad = 1;
    for (k = 0; k < m->nf; k++) {
        m->src[k] = next_int(&r, 0, 1);
        m->col[k] = next_int(&r, 0, LIMIT);
        m->flag[k] = next_int(&r, 0, m->lag);
        m->fdiff[k] = next_int(&r, 0, m->lag);
        m->src2[k] = next_int(&r, -1, 1);
        m->col2[k] = next_int(&r, 0, LIMIT);
        m->code[k] = next_int(&r, 0, 11);
        m->power[k] = next(&r);
        m->scale[k] = next(&r);
        m->offset[k] = next(&r);
        m->param[k] = next(&r);
        m->param2[k] = next(&r);
        m->weight[k] = next(&r);
        if (m->flag[k] + m->fdiff[k] > m->lag) r.bad = 1;
    }
    if (r.bad) goto bad;
    if (m->rep == 0) {
        next_array(&r, m->A, (size_t)m->nx * m->nx);
        next_array(&r, m->B, (size_t)m->nx * m->nu);
        next_array(&r, m->C, (size_t)m->ny * m->nx);
        next_array(&r, m->D, (size_t)m->ny * m->nu);
        next_array(&r, m->x0, (size_t)m->nx);
        next_array(&r, m->E, (size_t)m->nx * m->nt);
    } else if (m->rep == 1) {
        m->nl = next_int(&r, 1, LIMIT);
        m->na = next_int(&r, 0, m->lag);
        if (r.bad || m->nl - 1 > m->lag || m->nx != 0) goto bad;
        /* ARX arrays need their own room */
        m->G = (double *)calloc((size_t)m->nl * m->ny * m->nu + (size_t)m->ny * m->na * m->ny +
                                    (size_t)m->ny + (size_t)m->ny * m->nt + 1,
                                sizeof(double));
        m->Gused = (int *)calloc((size_t)m->nl + 1, sizeof(int));
        if (!m->G || !m->Gused) goto bad;
        m->Acat = m->G + (size_t)m->nl * m->ny * m->nu;
        m->off = m->Acat + (size_t)m->ny * m->na * m->ny;
        m->coef_t = m->off + m->ny;
        next_array(&r, m->G, (size_t)m->nl * m->ny * m->nu);
        next_array(&r, m->Acat, (size_t)m->ny * m->na * m->ny);
        next_array(&r, m->off, (size_t)m->ny);
        next_array(&r, m->coef_t, (size_t)m->ny * m->nt);
        for (k = 0; k < m->nl; k++) {
            size_t j, n = (size_t)m->ny * m->nu;
            for (j = 0; j < n; j++)
                if (m->G[(size_t)k * n + j] != 0.0) m->Gused[k] = 1;
        }
    } else {
        next_array(&r, m->coef, (size_t)m->nt * m->nx);
        for (k = 0; k < m->ny; k++) m->outst[k] = next_int(&r, 0, m->nx - 1);
        next_array(&r, m->x0, (size_t)m->nx);
    }
    if (next(&r) != TK_MAGIC || r.i != r.n) r.bad = 1;
    /* every term reads a column that exists; ARX outputs only from past samples */
    for (k = 0; k < m->nf && !r.bad; k++) {
        if (!column_ok(m, m->src[k], m->col[k], m->flag[k])) r.bad = 1;
        /* the minus signal of a relative factor: the same checks */
        if (m->src2[k] >= 0 && !column_ok(m, m->src2[k], m->col2[k], m->flag[k])) r.bad = 1;
    }
    if (r.bad) goto bad;
    free(raw);

    /* the state layout */
    i = TK_HEADER;
    m->s_x = i; i += m->nx;
    m->s_uh = i; i += m->H * m->nu;
    m->s_yh = i; i += m->H * m->ny;
    m->s_xh = i; i += m->H * m->nx;
    m->s_blk = i;
    nbi_state = 0;
    {
        double total = 0.0; /* the blocks' state, checked before any int offset is formed */
        for (k = 0; k < m->nbi + m->nbo; k++) {
            blocks = k < m->nbi ? &m->bi[k] : &m->bo[k - m->nbi];
            total += 4.0 + (blocks->kind == 0 ? blocks->n + 1.0 : 0.0);
        }
        if (total + i > MAX_VALUES) {
            tk_free(m);
            TK_SNPRINTF(why, nwhy, "the model resource %s asks for too much state", path);
            return 1;
        }
    }
    for (k = 0; k < m->nbi + m->nbo; k++) {
        blocks = k < m->nbi ? &m->bi[k] : &m->bo[k - m->nbi];
        blocks->off = i + nbi_state;
        nbi_state += 4 + (blocks->kind == 0 ? blocks->n + 1 : 0);
    }
    i += nbi_state;
    m->s_u = i; i += m->nu;
    m->s_ratio = i; i += 4;
    m->s_fs = i; i += 2 * m->nf;
    m->ns = i;
    m->S = (double *)calloc((size_t)m->ns, sizeof(double));
    if (!m->S) {
        tk_free(m);
        TK_SNPRINTF(why, nwhy, "out of memory for the model state");
        return 1;
    }
    tk_reset(m);
    return 0;
bad:
    free(raw);
    tk_free(m);
    TK_SNPRINTF(why, nwhy, "the model resource %s is corrupt or of another tendonkit version", path);
    return 1;
}

void tk_free(tk_model *m) {
    free(m->store);
    free(m->bi);
    free(m->bo);
    free(m->ptr);
    free(m->G);
    free(m->Gused);
    free(m->S);
    memset(m, 0, sizeof(*m));
}

int tk_state_ok(const tk_model *m, const double *S) {
    int k;
    if (!(S[TK_HEAD] >= -1 && S[TK_HEAD] < m->H && S[TK_HEAD] == floor(S[TK_HEAD]))) return 0;
    if (!(S[TK_COUNT] >= 0 && S[TK_COUNT] <= m->H)) return 0;
    if (!(S[TK_TIME_INDEX] >= 0) || !(S[TK_DEAD] == 0.0 || S[TK_DEAD] == 1.0)) return 0;
    for (k = 0; k < m->nbi + m->nbo; k++) {
        const tk_block *b = k < m->nbi ? &m->bi[k] : &m->bo[k - m->nbi];
        double head = S[b->off + 3];
        if (b->kind == 0 && !(head >= 0 && head <= b->n && head == floor(head))) return 0;
    }
    return 1;
}

void tk_reset(tk_model *m) {
    int k;
    memset(m->S, 0, (size_t)m->ns * sizeof(double));
    for (k = 0; k < m->nx; k++) m->S[m->s_x + k] = m->x0[k];
    for (k = 0; k < m->nu; k++) m->S[m->s_u + k] = m->u0[k];
    for (k = 0; k < 4; k++) m->S[m->s_ratio + k] = m->ratio0[k];
    for (k = 0; k < 2 * m->nf; k++) m->S[m->s_fs + k] = NAN; /* operators not started */
}

/* ------------------------------------------------------------------ blocks */

static double block_value(const tk_model *m, const tk_block *b, double s) {
    const double *st = m->S + b->off; /* started, v (a section: w1), s0, head (a section: w2), fifo */
    int started = st[0] != 0.0;
    double v, z;
    switch (b->kind) {
    case 1: /* dead zone */
        z = s - b->p1;
        return nsign(z) * pmax(fabs(z) - b->p0, 0.0) + b->p1;
    case 2: /* saturation */
        return pmin(pmax(s, b->p0), b->p1);
    case 0: { /* delay: fifo[i] (0 oldest) holds s[k - n - 1 + i] */
        int n = b->n, head = (int)st[3];
        double a = b->p1;
        if ((n == 0 && a == 0.0) || !started) return s;
        {
            double f0 = st[4 + (head + 1) % (n + 1)];
            double f1 = n ? st[4 + (head + 2) % (n + 1)] : s;
            return (1.0 - a) * f1 + a * f0;
        }
    }
    case 3: /* play */
        v = started ? st[1] : s;
        if (s - v > b->p0) v = s - b->p0;
        else if (s - v < -b->p0) v = s + b->p0;
        return v;
    case 4: /* first-order lag */
        return started ? st[1] + st[2] : s;
    case 6: /* polynomial: c0 + c1 s + c2 s^2 + c3 s^3 */
        return b->p0 + s * (b->p1 + s * (b->p2 + s * b->p3));
    case 7: /* second-order section (1 + b1 q^-1 + b2 q^-2) / (1 + a1 q^-1 + a2 q^-2) at rest
               at its first input s0: g s0 + (s - s0) + w1, g its static gain; scipy's order */
        return started ? (st[1] + (s - st[2])) + b->g * st[2] : b->g * s;
    default: /* rate limit */
        v = started ? st[1] : s;
        return v + pmin(pmax(s - v, -b->p0), b->p0);
    }
}

static double block_commit(tk_model *m, const tk_block *b, double s) {
    double out = block_value(m, b, s);
    double *st = m->S + b->off;
    int started = st[0] != 0.0;
    if (b->kind == 0) {
        int n = b->n, k;
        if (n || b->p1 != 0.0) {
            if (!started) {
                for (k = 0; k <= n; k++) st[4 + k] = s;
                st[3] = n; /* newest at the end */
            } else {
                int head = ((int)st[3] + 1) % (n + 1);
                st[4 + head] = s;
                st[3] = head;
            }
        }
    } else if (b->kind == 3 || b->kind == 5) {
        st[1] = out;
    } else if (b->kind == 4) {
        double a = b->p0;
        if (!started) {
            st[2] = s;
            st[1] = 0.0;
        }
        st[1] = (s - st[2]) * (1.0 - a) - st[1] * (-a);
    } else if (b->kind == 7) { /* transposed direct form II on x = s - s0: st[1], st[3] */
        double x, z, w1;
        if (!started) {
            st[2] = s;
            st[1] = 0.0;
            st[3] = 0.0;
        }
        x = s - st[2];
        z = st[1] + x;
        w1 = (st[3] + x * b->p0) - z * b->p2;
        st[3] = x * b->p1 - z * b->p3;
        st[1] = w1;
    }
    st[0] = 1.0;
    return out;
}

static void chain(tk_model *m, const tk_block *b, int nb, double *x, int commit) {
    int k;
    for (k = 0; k < nb; k++)
        x[b[k].sig] = commit ? block_commit(m, &b[k], x[b[k].sig]) : block_value(m, &b[k], x[b[k].sig]);
}

/* ------------------------------------------------------------------ histories */

/* Row `back` samples before the newest (0: the newest) of a history of width w at offset o. */
static double *hist(tk_model *m, int o, int w, int back) {
    /* 0 <= head < H and 0 <= back < H (every lag was checked against H at load): one
     * conditional wrap instead of two integer divisions per read */
    int row = (int)m->S[TK_HEAD] - back;
    if (row < 0) row += m->H;
    return m->S + o + (size_t)row * w;
}

static void push(tk_model *m, const double *u, const double *y, const double *x) {
    int head = ((int)m->S[TK_HEAD] + 1) % m->H;
    m->S[TK_HEAD] = head;
    if (m->nu) memcpy(m->S + m->s_uh + (size_t)head * m->nu, u, (size_t)m->nu * sizeof(double));
    if (y) memcpy(m->S + m->s_yh + (size_t)head * m->ny, y, (size_t)m->ny * sizeof(double));
    if (x && m->nx) memcpy(m->S + m->s_xh + (size_t)head * m->nx, x, (size_t)m->nx * sizeof(double));
    if (m->S[TK_COUNT] < m->H) m->S[TK_COUNT] += 1;
}

/* Before the first sample: pad the histories as the reference does. */
static void pad(tk_model *m, const double *ub) {
    int k;
    if (m->S[TK_TIME_INDEX] != 0.0 || m->S[TK_COUNT] != 0.0) return;
    m->S[TK_HEAD] = -1;
    for (k = 0; k < m->lag; k++) {
        int head = ((int)m->S[TK_HEAD] + 1 + m->H) % m->H, j;
        double *u = m->S + m->s_uh + (size_t)head * m->nu;
        double *y = m->S + m->s_yh + (size_t)head * m->ny;
        m->S[TK_HEAD] = head;
        for (j = 0; j < m->nu; j++) u[j] = m->rep == 1 ? 0.0 : ub[j];
        for (j = 0; j < m->ny; j++) y[j] = 0.0;
        if (m->rep == 2)
            memcpy(m->S + m->s_xh + (size_t)head * m->nx, m->S + m->s_x,
                   (size_t)m->nx * sizeof(double));
        m->S[TK_COUNT] += 1;
    }
    if (m->lag == 0) m->S[TK_HEAD] = -1;
}

/* ------------------------------------------------------------------ terms */

static double fn(int code, double z, double power, double param) {
    double r;
    switch (code) {
    case 0:
        if (power == 1.0) return z;
        if (power == 2.0) return z * z;
        if (power == 3.0) return z * z * z;
        if (power >= 4.0 && power <= 16.0 && power == floor(power)) {
            /* small integer powers by squaring (within a few ulp of pow, much cheaper) */
            int e = (int)power;
            double b = z, acc = 1.0;
            while (e) {
                if (e & 1) acc *= b;
                b *= b;
                e >>= 1;
            }
            return acc;
        }
        return pow(z, power);
    case 1: return sin(z);
    case 2: return cos(z);
    case 3: return tanh(z);
    case 4: return nsign(z);
    case 5: return fabs(z);
    case 6: /* dead zone: sign(z) max(|z| - p, 0) */
        return nsign(z) * pmax(fabs(z) - param, 0.0);
    case 7: return pmin(pmax(z, -param), param);
    default:
        r = z - param;
        return pmax(r, 0.0);
    }
}

/* The value of one factor's signal `back` samples before the current one (see reads below). */
static double read(tk_model *m, int src, int c, int back, const double *ub) {
    if (m->rep == 1) { /* ARX: the current input, or committed samples (newest = 1 back) */
        if (src == 0) return back == 0 ? ub[c] : hist(m, m->s_uh, m->nu, back - 1)[c];
        return hist(m, m->s_yh, m->ny, back - 1)[c];
    }
    if (m->rep == 2) /* sparse map: states or inputs, the current sample already pushed */
        return src == 0 ? hist(m, m->s_xh, m->nx, back)[c] : hist(m, m->s_uh, m->nu, back)[c];
    return src == 0 ? hist(m, m->s_uh, m->nu, back)[c] : hist(m, m->s_yh, m->ny, back)[c];
}

/* Factor f's reading of column c of buffer src: its sample `flag` back, minus the one `fdiff`
 * further back when the factor is differenced. */
static double reading(tk_model *m, int src, int c, int f, const double *ub) {
    double v = read(m, src, c, m->flag[f], ub);
    return m->fdiff[f] ? v - read(m, src, c, m->flag[f] + m->fdiff[f], ub) : v;
}

/* One step of an operator with a memory (code 9 play, 10 Bouc-Wen, 11 slew lag;
 * tendonkit.terms._step_stateful) from its state st (NaN: not started); the new state is written
 * only when `commit`. */
static double memory(int code, double z, double param, double param2, double *st, int commit) {
    double a = st[0], h, d;
    if (code == 9) {
        double p = a != a ? z : pmin(pmax(a, z - param), z + param);
        if (commit) st[0] = p;
        return p;
    }
    if (code == 11) {
        double r = a != a ? z : a + pmin(pmax(param * (z - a), -param2), param2);
        if (commit) st[0] = r;
        return r;
    }
    if (a != a) {
        if (commit) { st[0] = z; st[1] = 0.0; }
        return 0.0;
    }
    d = z - a;
    h = st[1] + d - param * fabs(d) * st[1] - param2 * d * fabs(st[1]);
    if (commit) { st[0] = z; st[1] = h; }
    return h;
}

static void terms(tk_model *m, const double *ub, int commit) {
    int t, f;
    for (t = 0; t < m->nt; t++) {
        double prod = 1.0;
        for (f = m->ptr[t]; f < m->ptr[t + 1]; f++) {
            double z = reading(m, m->src[f], m->col[f], f, ub);
            if (m->src2[f] >= 0) /* relative to a second signal (tendonkit.terms.Factor.minus) */
                z = z - m->weight[f] * reading(m, m->src2[f], m->col2[f], f, ub);
            z = (z - m->offset[f]) * m->scale[f];
            if (m->code[f] >= 9)
                prod *= memory(m->code[f], z, m->param[f], m->param2[f], m->S + m->s_fs + 2 * f,
                               commit);
            else
                prod *= fn(m->code[f], z, m->power[f], m->param[f]);
        }
        m->theta[t] = prod;
    }
}

/* ------------------------------------------------------------------ the representation */

static void arx_output(tk_model *m, const double *ub, double *y, int commit) {
    int i, j, l, w;
    size_t n = (size_t)m->ny * m->nu;
    pad(m, ub);
    for (i = 0; i < m->ny; i++) y[i] = m->off[i];
    for (l = 0; l < m->nl; l++) {
        const double *row, *g = m->G + (size_t)l * n;
        if (!m->Gused[l]) continue;
        row = l == 0 ? ub : hist(m, m->s_uh, m->nu, l - 1);
        for (i = 0; i < m->ny; i++) {
            double acc = 0.0;
            for (j = 0; j < m->nu; j++) acc += g[(size_t)i * m->nu + j] * row[j];
            y[i] = y[i] + acc;
        }
    }
    if (m->na) {
        for (i = 0; i < m->ny; i++) {
            double acc = 0.0;
            for (w = 0; w < m->na; w++) {
                const double *past = hist(m, m->s_yh, m->ny, w);
                for (j = 0; j < m->ny; j++) acc += m->Acat[(size_t)i * m->na * m->ny + (size_t)w * m->ny + j] * past[j];
            }
            y[i] = y[i] - acc;
        }
    }
    if (m->nt) {
        terms(m, ub, commit);
        for (i = 0; i < m->ny; i++) {
            double acc = 0.0;
            int t;
            for (t = 0; t < m->nt; t++) acc += m->coef_t[(size_t)i * m->nt + t] * m->theta[t];
            y[i] = y[i] + acc;
        }
    }
}

/* Modelled outputs before the output blocks for block-processed inputs ub (NaN once dead). */
static void raw_output(tk_model *m, const double *ub, double *y, int commit) {
    int i, j;
    if (m->S[TK_DEAD] != 0.0) {
        for (i = 0; i < m->ny; i++) y[i] = NAN;
        return;
    }
    if (m->rep == 0) {
        const double *x = m->S + m->s_x;
        for (i = 0; i < m->ny; i++) {
            double a = 0.0, b = 0.0;
            for (j = 0; j < m->nx; j++) a += m->C[(size_t)i * m->nx + j] * x[j];
            for (j = 0; j < m->nu; j++) b += m->D[(size_t)i * m->nu + j] * ub[j];
            y[i] = a + b;
        }
    } else if (m->rep == 2) {
        for (i = 0; i < m->ny; i++) y[i] = m->S[m->s_x + m->outst[i]];
    } else {
        arx_output(m, ub, y, commit);
    }
    for (i = 0; i < m->ny; i++) {
        if (!TK_FINITE(y[i])) {
            m->S[TK_DEAD] = 1.0;
            for (j = 0; j < m->ny; j++) y[j] = NAN;
            return;
        }
    }
}

static void update(tk_model *m, const double *ub, const double *y) {
    int i, j, t;
    double *x = m->S + m->s_x;
    if (m->rep == 0) {
        if (m->nt) {
            pad(m, ub);
            push(m, ub, y, NULL);
            terms(m, ub, 1);
        }
        for (i = 0; i < m->nx; i++) {
            double a = 0.0, b = 0.0, e = 0.0;
            for (j = 0; j < m->nx; j++) a += m->A[(size_t)i * m->nx + j] * x[j];
            for (j = 0; j < m->nu; j++) b += m->B[(size_t)i * m->nu + j] * ub[j];
            for (t = 0; t < m->nt; t++) e += m->E[(size_t)i * m->nt + t] * m->theta[t];
            m->xn[i] = m->nt ? a + b + e : a + b;
        }
        memcpy(x, m->xn, (size_t)m->nx * sizeof(double));
        if (!m->nt) return; /* divergence shows in the outputs */
    } else if (m->rep == 1) {
        pad(m, ub);
        push(m, ub, y, NULL);
        return;
    } else {
        pad(m, ub);
        push(m, ub, NULL, x);
        terms(m, ub, 1);
        for (i = 0; i < m->nx; i++) {
            double acc = 0.0;
            for (t = 0; t < m->nt; t++) acc += m->theta[t] * m->coef[(size_t)t * m->nx + i];
            m->xn[i] = acc;
        }
        memcpy(x, m->xn, (size_t)m->nx * sizeof(double));
    }
    for (i = 0; i < m->nx; i++)
        if (!TK_FINITE(x[i])) m->S[TK_DEAD] = 1.0;
}

/* ------------------------------------------------------------------ kinematics */

static void kinematics(const tk_model *m, const double *y, const double *ratio, double *out) {
    double q[6], x0 = 1, x1 = 0, x2 = 0, y0 = 0, y1 = 1, y2 = 0, z0 = 0, z1 = 0, z2 = 1;
    double p0 = 0, p1 = 0, p2 = 0;
    int i;
    double q1 = y[m->iq1], q2 = y[m->iq2];
    /* expand_joints: (q1, q2) @ ratio_matrix.T, one ratio per joint and a zero for the other */
    q[0] = q1 * 1.0 + q2 * 0.0;
    q[1] = q1 * 0.0 + q2 * 1.0;
    q[2] = q1 * ratio[0] + q2 * 0.0;
    q[3] = q1 * 0.0 + q2 * ratio[1];
    q[4] = q1 * ratio[2] + q2 * 0.0;
    q[5] = q1 * 0.0 + q2 * ratio[3];
    for (i = 0; i < 4; i++) out[i] = q[2 + i];
    for (i = 0; i < 6; i++) {
        double qi = q[i], s = sin(qi), c = cos(qi), n0, n1, n2, radius = m->R[i];
        double bend = radius * (2 * sin(0.5 * qi) - s);
        double lift = radius * (2 * cos(0.5 * qi) - 1 - c);
        if (i % 2 == 0) { /* pan joints bend toward the link's x axis */
            n0 = s * x0 + c * z0; n1 = s * x1 + c * z1; n2 = s * x2 + c * z2;
            p0 = p0 + bend * x0 + lift * z0 + m->pitch * n0;
            p1 = p1 + bend * x1 + lift * z1 + m->pitch * n1;
            p2 = p2 + bend * x2 + lift * z2 + m->pitch * n2;
            x0 = c * x0 - s * z0; x1 = c * x1 - s * z1; x2 = c * x2 - s * z2;
        } else {
            n0 = s * y0 + c * z0; n1 = s * y1 + c * z1; n2 = s * y2 + c * z2;
            p0 = p0 + bend * y0 + lift * z0 + m->pitch * n0;
            p1 = p1 + bend * y1 + lift * z1 + m->pitch * n1;
            p2 = p2 + bend * y2 + lift * z2 + m->pitch * n2;
            y0 = c * y0 - s * z0; y1 = c * y1 - s * z1; y2 = c * y2 - s * z2;
        }
        z0 = n0; z1 = n1; z2 = n2;
    }
    out[4] = p0 + m->tool * z0;
    out[5] = p1 + m->tool * z1;
    out[6] = p2 + m->tool * z2;
}

/* ------------------------------------------------------------------ public */

/* Outputs (and kinematics) from y after the output blocks; NaN once dead or where an output
 * curve overflowed (as simulate gives). */
static void finish(tk_model *m, double *y, double *out) {
    int i, dead = m->S[TK_DEAD] != 0.0;
    for (i = 0; i < m->ny; i++) {
        out[i] = y[i];
        if (!TK_FINITE(y[i])) dead = 1;
    }
    if (m->kin) kinematics(m, y, m->S + m->s_ratio, out + m->ny);
    if (dead)
        for (i = 0; i < m->nout; i++) out[i] = NAN;
}

void tk_outputs(tk_model *m, double *out) {
    memcpy(m->ub, m->S + m->s_u, (size_t)m->nu * sizeof(double));
    chain(m, m->bi, m->nbi, m->ub, 0);
    raw_output(m, m->ub, m->yraw, 0);
    chain(m, m->bo, m->nbo, m->yraw, 0);
    finish(m, m->yraw, out);
}

int tk_advance(tk_model *m) {
    int i;
    memcpy(m->ub, m->S + m->s_u, (size_t)m->nu * sizeof(double));
    chain(m, m->bi, m->nbi, m->ub, 1);
    raw_output(m, m->ub, m->yraw, 1);
    if (m->S[TK_DEAD] == 0.0) update(m, m->ub, m->yraw);
    m->S[TK_TIME_INDEX] += 1;
    chain(m, m->bo, m->nbo, m->yraw, 1);
    for (i = 0; i < m->ny; i++)
        if (!TK_FINITE(m->yraw[i])) m->S[TK_DEAD] = 1.0; /* an output curve overflowed */
    return m->S[TK_DEAD] != 0.0;
}
