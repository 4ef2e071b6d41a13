/* The companion's control step after the state filter, in one call.
 *
 * step(params, state, dt, skip, q, q_dot, q_ddot, qd, qd_dot, qd_ddot, tau_applied, out
 *      [, est_q, est_q_dot, est_q_ddot, est_tau, est_skip])
 * runs what companion.control.flight.FlightControl.step runs in Python, in the same order
 * and with the same floating-point operations:
 *   1. the model's pieces of M, C, G at (q, q_dot) (the generated mcg_eval of _mcg.c), and
 *      at the estimator's inputs if they are given (an earlier cycle's, with a central-
 *      difference q_ddot: companion.estimation.inputs; est_skip replaces skip),
 *   2. the estimator on the used rows: the paper's observer and gradient update (eqs.
 *      estimator, update) or RLS with forgetting, optionally with the thrust scale as a
 *      fourth unknown; skip reasons, projection onto the physically consistent set; then
 *      the excitation monitor,
 *   3. the tilt reference applied to the desired state,
 *   4. the augmented passivity-based law (eq. tau2), adaptive or with theta fixed at the
 *      empty-arm values (the non-adaptive baseline), with the measured motion on the rows
 *      of Params.measured, plus the horizontal integral trim,
 *   5. the attitude/thrust setpoint (eq. phid, thrust model), then the tilt reference's
 *      step toward the new roll and pitch,
 *   6. if Params.ff_on, the roll/pitch offset of PX4's tilt loop inverted for the model's
 *      torque on the tilt rows at the reference attitude, low-passed
 *      (companion.control.attitude_feedforward).
 * The Python classes (companion.estimation.estimator, companion.control.laws, companion.control.trajectory,
 * companion.control.setpoints) are the reference; tests/test_compiled_step.py compares the two.
 *
 * Everything the step keeps between calls lives in `state` and everything fixed in
 * `params`: float64 buffers owned by Python (companion.control.compiled_step), laid out as the
 * structs below (all doubles, no padding; their offsets are exported as LAYOUT).
 * Booleans and counts are stored as doubles (0.0 / 1.0, exact integers).
 *
 * Built with -ffp-contract=off so that no compiler fuses a * b + c into one rounding (an
 * FMA the Python reference does not do).
 */
#define MCG_EVAL_ONLY
#include "../model/_mcg.c"
#undef MCG_EVAL_ONLY

#include <stddef.h>
#include <stdio.h>

#define NQ 8
#define PIECE 136 /* one piece of the model: 8 rows of [M row | C row | G] */
#define PI 3.14159265358979311600
#define N_SKIP 5

typedef struct {
    double model[14];       /* companion.model.ModelParameters.vector() */
    double rls;             /* 1: RLS, 0: the paper's estimator */
    double has_scale;       /* 1: the thrust scale is estimated */
    double n_rows;          /* used rows of q (1..8) */
    double rows[NQ];        /* their indices, increasing */
    double yaw_index;       /* index of row 5 among the used rows, or -1 */
    double fixed;           /* 1: eq. tau2 with fixed_xi (non-adaptive) */
    double fixed_xi[4];
    double k[NQ];           /* eq. tau2: k and k Lambda */
    double k_lam[NQ];
    double lam_xy[2];       /* Lambda on x, y (the trim's sliding variable) */
    double gamma[3];        /* paper estimator */
    double c_star[NQ];      /* paper estimator, per used row */
    double k_star[NQ];
    double qhat_dot0[NQ];
    double m2_min, m2_max, l2; /* ThetaBounds */
    double s_initial, s_low, s_high, s_gamma, s_drift2, s_var_max; /* ThrustScaleModel */
    double forgetting, p_trace_max;
    double p0[9];
    double r_forgotten[NQ]; /* diagonal of R / lambda, per used row */
    double window_s, sample_period_s, excitation_min, spread_max, window_samples;
    double weight[NQ * 3];  /* ExcitationMonitor.weight, per used row */
    double tilt_w;          /* TiltReference */
    double tilt_max, thrust_max, thrust_min_rel; /* mapping and ThrustModel */
    double compensate;      /* 1: the mapped force is divided by the thrust scale */
    double trim_gain, trim_limit; /* HorizontalTrim */
    double measured[NQ];    /* 1: eq. tau2 takes the measured q_dot, q_ddot on this row */
    double com_from_joints; /* 1: the RLS rows x, y, z learn m2 (and s) only */
    double ff_on;           /* 1: AttitudeLoopInverse, with (roll, pitch) pairs: */
    double ff_att_p[2], ff_rate_p[2], ff_rate_i[2], ff_int_lim[2], ff_torque[2];
    double ff_max[2];       /* its offset limits (roll, pitch) [rad] */
    double ff_tf;           /* its torque filter's time constant [s] */
} Params;

typedef struct {
    double theta[3];
    double frozen;
    double thrust_scale;
    double scale_held;      /* 1: s held (no gain) until the monitor is confident */
    double calibrating;     /* 1: theta held, s learnt (its covariance block is zero) */
    double s_comp;          /* the last calibrated s, which the compensation divides by */
    double skipped[N_SKIP]; /* counts by companion.estimation.estimator.Skip, in its order */
    double qhat_valid;
    double qhat[NQ];        /* paper observer, per used row */
    double p[9], p_s[3], var_s; /* RLS covariance */
    double info[9], excitation, spread, since_sample, samples; /* ExcitationMonitor */
    double ring_len, ring_head; /* the monitor's m2 and lc windows, at `ring` */
    double tilt_x[2], tilt_v[2], tilt_a[2];
    double trim_force[2], trim_active;
    double ff_torque_f[2];  /* AttitudeLoopInverse.torque_n_m (low-passed) */
    double ff_int[2];       /* AttitudeLoopInverse.integral */
    double ring[];          /* m2 window, then lc window (window_samples each) */
} State;

/* Offsets of `out`. */
enum {
    OUT_TAU = 0,
    OUT_ROLL = 8, OUT_PITCH, OUT_YAW, OUT_THRUST, OUT_THRUST_REL, OUT_TILT_SAT, OUT_THRUST_SAT,
    OUT_THETA = 15, OUT_EXCITATION = 18, OUT_SPREAD, OUT_CONFIDENT, OUT_FROZEN, OUT_SCALE,
    OUT_THETA_USED = 23,
    OUT_REF_Q = 26, OUT_REF_QD = 34, OUT_REF_QDD = 42,
    OUT_SIZE = 50
};

/* Python's float % (sign of the divisor), as in CPython's float_rem. */
static double py_mod(double a, double b)
{
    double r = fmod(a, b);
    if (r != 0.0) {
        if ((b < 0.0) != (r < 0.0)) r += b;
    } else {
        r = copysign(0.0, b);
    }
    return r;
}

/* Python's max(a, b) and min(a, b) on floats (the first argument wins ties). */
static double py_max(double a, double b) { return b > a ? b : a; }
static double py_min(double a, double b) { return b < a ? b : a; }

static double wrap_pi(double a) { return py_mod(a + PI, 2.0 * PI) - PI; }

/* Y^T rows k = 0..3 of row i: M_k[i] a + C_k[i] v + G_k[i] (the _mcg.regress product). */
static void regress(const double *pieces, const double *v, const double *a, double *yt)
{
    const double *p = pieces;
    for (int r = 0; r < 32; ++r, p += 17) {
        double acc = p[16];
        for (int j = 0; j < 8; ++j) acc += p[j] * a[j] + p[8 + j] * v[j];
        yt[r] = acc;
    }
}

/* ThetaBounds.clip; 0 on a non-finite estimate. */
static int clip_theta(const Params *P, double *m2, double *m3, double *m4)
{
    if (!(isfinite(*m2) && isfinite(*m3) && isfinite(*m4))) {
        char msg[160];
        snprintf(msg, sizeof msg, "non-finite parameter estimate (%.17g, %.17g, %.17g)", *m2,
                 *m3, *m4);
        PyErr_SetString(PyExc_FloatingPointError, msg);
        return 0;
    }
    double l2 = P->l2;
    *m2 = py_min(py_max(*m2, P->m2_min), P->m2_max);
    *m3 = py_min(py_max(*m3, 0.0), *m2 * l2);
    *m4 = py_min(py_max(*m4, *m3 * *m3 / *m2), *m2 * l2 * l2);
    return 1;
}

/* ThrustScaleModel.clip; 0 on a non-finite estimate. */
static int clip_scale(const Params *P, double *s)
{
    if (!isfinite(*s)) {
        char msg[80];
        snprintf(msg, sizeof msg, "non-finite thrust scale estimate %.17g", *s);
        PyErr_SetString(PyExc_FloatingPointError, msg);
        return 0;
    }
    *s = py_min(py_max(*s, P->s_low), P->s_high);
    return 1;
}

/* Solve A X = B for X (A n x n, B n x m, row-major; both overwritten, X in B) by Gaussian
 * elimination with partial pivoting (LAPACK dgesv's method); 0 if A is singular. */
static int solve(int n, int m, double *A, double *B)
{
    for (int c = 0; c < n; ++c) {
        int piv = c;
        for (int r = c + 1; r < n; ++r)
            if (fabs(A[r * n + c]) > fabs(A[piv * n + c])) piv = r;
        if (A[piv * n + c] == 0.0) return 0;
        if (piv != c) {
            for (int j = 0; j < n; ++j) {
                double t = A[c * n + j]; A[c * n + j] = A[piv * n + j]; A[piv * n + j] = t;
            }
            for (int j = 0; j < m; ++j) {
                double t = B[c * m + j]; B[c * m + j] = B[piv * m + j]; B[piv * m + j] = t;
            }
        }
        for (int r = c + 1; r < n; ++r) {
            double f = A[r * n + c] / A[c * n + c];
            for (int j = c + 1; j < n; ++j) A[r * n + j] -= f * A[c * n + j];
            for (int j = 0; j < m; ++j) B[r * m + j] -= f * B[c * m + j];
        }
    }
    for (int c = n - 1; c >= 0; --c) {
        for (int j = 0; j < m; ++j) {
            double acc = B[c * m + j];
            for (int k = c + 1; k < n; ++k) acc -= A[c * n + k] * B[k * m + j];
            B[c * m + j] = acc / A[c * n + c];
        }
    }
    return 1;
}

/* Smallest eigenvalue of a symmetric 3 x 3 matrix (cyclic Jacobi rotations). */
static double min_eigenvalue3(const double *S)
{
    double a[3][3];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) a[i][j] = 0.5 * (S[3 * i + j] + S[3 * j + i]);
    for (int sweep = 0; sweep < 50; ++sweep) {
        double off = fabs(a[0][1]) + fabs(a[0][2]) + fabs(a[1][2]);
        if (off == 0.0) break;
        for (int p = 0; p < 2; ++p) {
            for (int q = p + 1; q < 3; ++q) {
                if (a[p][q] == 0.0) continue;
                double tau = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                double t = (tau >= 0.0 ? 1.0 : -1.0) / (fabs(tau) + sqrt(1.0 + tau * tau));
                double c = 1.0 / sqrt(1.0 + t * t), s = t * c;
                for (int k = 0; k < 3; ++k) { /* columns p, q */
                    double akp = a[k][p], akq = a[k][q];
                    a[k][p] = c * akp - s * akq;
                    a[k][q] = s * akp + c * akq;
                }
                for (int k = 0; k < 3; ++k) { /* rows p, q */
                    double apk = a[p][k], aqk = a[q][k];
                    a[p][k] = c * apk - s * aqk;
                    a[q][k] = s * apk + c * aqk;
                }
                a[p][q] = a[q][p] = 0.0;
            }
        }
    }
    return py_min(py_min(a[0][0], a[1][1]), a[2][2]);
}

/* (max - min) / mean of a window of positive samples (estimation._relative_range). */
static double relative_range(const double *v, int n)
{
    double lo = v[0], hi = v[0];
    for (int i = 1; i < n; ++i) {
        lo = py_min(lo, v[i]);
        hi = py_max(hi, v[i]);
    }
    return (hi - lo) / py_max(0.5 * (hi + lo), 1e-12);
}

/* ExcitationMonitor.update with the used rows' Y_theta (y: n x 4, row-major). */
static void monitor_update(const Params *P, State *S, double dt, const double *y, int n)
{
    S->since_sample += dt;
    if (S->since_sample < P->sample_period_s) return;
    double elapsed = isinf(S->since_sample) ? dt : S->since_sample;
    S->since_sample = 0.0;
    double a = py_min(elapsed / P->window_s, 1.0);
    double scaled[NQ * 3];
    for (int r = 0; r < n; ++r)
        for (int j = 0; j < 3; ++j) scaled[3 * r + j] = y[4 * r + j] * P->weight[3 * r + j];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
            double acc = 0.0;
            for (int r = 0; r < n; ++r) acc += scaled[3 * r + i] * scaled[3 * r + j];
            S->info[3 * i + j] += a * (acc - S->info[3 * i + j]);
        }
    int w = (int)P->window_samples, head = (int)S->ring_head, len = (int)S->ring_len;
    double m2 = S->theta[0];
    S->ring[head] = m2;
    S->ring[w + head] = S->theta[1] / m2;
    S->ring_head = (head + 1) % w;
    if (len < w) S->ring_len = ++len;
    if (len == w)
        S->spread = py_max(relative_range(S->ring, w), relative_range(S->ring + w, w));
    S->samples += 1.0;
    if (fmod(S->samples, 5.0) == 0.0) S->excitation = min_eigenvalue3(S->info);
}

/* PaperEstimator._step on the used rows (y: n x 4, row-major). */
static int paper_step(const Params *P, State *S, int n, double dt, const double *y,
                      const double *q, const double *qd, const double *tau_in)
{
    if (!S->qhat_valid) {
        for (int r = 0; r < n; ++r) S->qhat[r] = q[r] + dt * P->qhat_dot0[r];
        S->qhat_valid = 1.0;
        return 1;
    }
    double e[NQ], tau[NQ], ey[4] = {0.0, 0.0, 0.0, 0.0};
    for (int r = 0; r < n; ++r) e[r] = S->qhat[r] - q[r];
    int yaw = (int)P->yaw_index;
    if (yaw >= 0) e[yaw] = wrap_pi(e[yaw]);
    for (int r = 0; r < n; ++r)
        for (int k = 0; k < 4; ++k) ey[k] += e[r] * y[4 * r + k];
    double m2 = S->theta[0] + dt * P->gamma[0] * ey[0];
    double m3 = S->theta[1] + dt * P->gamma[1] * ey[1];
    double m4 = S->theta[2] + dt * P->gamma[2] * ey[2];
    if (!clip_theta(P, &m2, &m3, &m4)) return 0;
    S->theta[0] = m2; S->theta[1] = m3; S->theta[2] = m4;
    double xi[4] = {m2, m3, m4, 1.0};
    for (int r = 0; r < n; ++r) tau[r] = tau_in[r];
    if (P->has_scale) {
        if (!S->scale_held) {
            double ef = 0.0;
            for (int r = 0; r < n; ++r) ef += e[r] * (P->rows[r] < 3 ? tau[r] : 0.0);
            double s = S->thrust_scale - dt * P->s_gamma * ef;
            if (!clip_scale(P, &s)) return 0;
            S->thrust_scale = s;
        }
        for (int r = 0; r < n; ++r)
            if (P->rows[r] < 3) tau[r] = S->thrust_scale * tau[r];
    }
    for (int r = 0; r < n; ++r) {
        double dt_over_c = dt / P->c_star[r];
        double e_gain = 1.0 - dt_over_c * P->k_star[r];
        double yxi = 0.0;
        for (int k = 0; k < 4; ++k) yxi += y[4 * r + k] * xi[k];
        S->qhat[r] = q[r] + dt * qd[r] + e_gain * e[r] + dt_over_c * (tau[r] - yxi);
    }
    return 1;
}

/* RlsEstimator._step and _step_with_scale: m = 3 (theta) or 4 (theta, s). */
static int rls_step(const Params *P, State *S, int n, double dt, const double *y,
                    const double *tau)
{
    int m = P->has_scale ? 4 : 3;
    double h[NQ * 4], z[NQ], p[16], x[4], ph[4 * NQ], A[NQ * NQ], B[NQ * 4];
    for (int r = 0; r < n; ++r) {
        int thrust = P->has_scale && P->rows[r] < 3;
        int mass_only = P->com_from_joints && P->rows[r] < 3;
        double known = y[4 * r + 3];
        if (mass_only) known += y[4 * r + 1] * S->theta[1] + y[4 * r + 2] * S->theta[2];
        for (int j = 0; j < 3; ++j) h[m * r + j] = mass_only && j > 0 ? 0.0 : y[4 * r + j];
        if (m == 4) h[m * r + 3] = thrust ? -tau[r] : -0.0;
        z[r] = (thrust ? 0.0 : tau[r]) - known;
    }
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) p[m * i + j] = S->p[3 * i + j];
    for (int i = 0; i < 3; ++i) x[i] = S->theta[i];
    double var_s = S->var_s + P->s_drift2 * dt;
    if (m == 4) {
        for (int i = 0; i < 3; ++i) p[4 * i + 3] = p[12 + i] = S->p_s[i];
        p[15] = S->scale_held ? 0.0 : var_s;
        x[3] = S->thrust_scale;
    }
    /* ph = P H^T (m x n); A = H ph + R / lambda (n x n); B = ph^T, solved to gain^T */
    for (int i = 0; i < m; ++i)
        for (int r = 0; r < n; ++r) {
            double acc = 0.0;
            for (int j = 0; j < m; ++j) acc += p[m * i + j] * h[m * r + j];
            ph[n * i + r] = acc;
        }
    for (int r = 0; r < n; ++r) {
        for (int c = 0; c < n; ++c) {
            double acc = 0.0;
            for (int j = 0; j < m; ++j) acc += h[m * r + j] * ph[n * j + c];
            A[n * r + c] = acc + (r == c ? P->r_forgotten[r] : 0.0);
        }
        for (int i = 0; i < m; ++i) B[m * r + i] = ph[n * i + r];
    }
    if (!solve(n, m, A, B)) {
        /* numpy.linalg.solve raises LinAlgError, a ValueError (before any state changed) */
        PyErr_SetString(PyExc_ValueError, "Singular matrix");
        return 0;
    }
    /* gain[i][r] = B[r][i]; x += gain (z - H x) */
    double innov[NQ], xn[4];
    for (int r = 0; r < n; ++r) {
        double hx = 0.0;
        for (int j = 0; j < m; ++j) hx += h[m * r + j] * x[j];
        innov[r] = z[r] - hx;
    }
    for (int i = 0; i < m; ++i) {
        double acc = 0.0;
        for (int r = 0; r < n; ++r) acc += B[m * r + i] * innov[r];
        xn[i] = x[i] + acc;
    }
    double m2 = xn[0], m3 = xn[1], m4 = xn[2];
    if (!clip_theta(P, &m2, &m3, &m4)) return 0;
    if (m == 4) {
        double s = xn[3];
        if (!clip_scale(P, &s)) return 0;
        S->thrust_scale = s;
    }
    S->theta[0] = m2; S->theta[1] = m3; S->theta[2] = m4;
    /* P = (P - gain ph^T) / lambda, symmetrised, then the caps */
    double pn[16];
    for (int i = 0; i < m; ++i)
        for (int j = 0; j < m; ++j) {
            double acc = 0.0;
            for (int r = 0; r < n; ++r) acc += B[m * r + i] * ph[n * j + r];
            pn[m * i + j] = (p[m * i + j] - acc) / P->forgetting;
        }
    for (int i = 0; i < m; ++i)
        for (int j = 0; j < m; ++j) p[m * i + j] = 0.5 * (pn[m * i + j] + pn[m * j + i]);
    double trace = p[0] + p[m + 1] + p[2 * m + 2];
    if (m == 3) {
        if (trace > P->p_trace_max) {
            double f = P->p_trace_max / trace;
            for (int i = 0; i < 9; ++i) p[i] *= f;
        }
        for (int i = 0; i < 9; ++i) S->p[i] = p[i];
        return 1;
    }
    double d[4] = {1.0, 1.0, 1.0, 1.0};
    if (trace > P->p_trace_max) d[0] = d[1] = d[2] = sqrt(P->p_trace_max / trace);
    if (p[15] > P->s_var_max) d[3] = sqrt(P->s_var_max / p[15]);
    for (int i = 0; i < 4; ++i)
        for (int j = 0; j < 4; ++j) p[4 * i + j] *= d[i] * d[j];
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) S->p[3 * i + j] = p[4 * i + j];
        S->p_s[i] = p[4 * i + 3];
    }
    S->var_s = S->scale_held ? py_min(var_s / P->forgetting, P->s_var_max) : p[15];
    return 1;
}

/* tilt_from_force + attitude_thrust_setpoint (eq. phid, ThrustModel) into out. */
static void setpoint(const Params *P, const double *force, double yaw, double yaw_d,
                     double *out)
{
    double floor_n = P->thrust_min_rel * P->thrust_max;
    double fz = force[2];
    int lifted = !(fz >= floor_n && fz > 0.0);
    double fx = force[0], fy = force[1], lz = lifted ? floor_n : fz;
    double phi = 0.0, theta = 0.0;
    int tilt_sat = 1;
    if (lz > 0.0) {
        double c = cos(yaw), s = sin(yaw);
        theta = (c * fx + s * fy) / lz;
        phi = (s * fx - c * fy) / lz;
        double tilt = hypot(phi, theta);
        tilt_sat = tilt > P->tilt_max;
        if (tilt_sat) {
            double scale = P->tilt_max / tilt;
            phi = phi * scale;
            theta = theta * scale;
        }
    }
    double thrust = py_max(fz, 0.0) / (cos(phi) * cos(theta));
    double rel = thrust / P->thrust_max;
    double clipped = py_min(py_max(rel, P->thrust_min_rel), 1.0);
    out[OUT_ROLL] = phi;
    out[OUT_PITCH] = theta;
    out[OUT_YAW] = yaw_d;
    out[OUT_THRUST] = P->thrust_max * py_min(py_max(clipped, 0.0), 1.0);
    out[OUT_THRUST_REL] = clipped;
    out[OUT_TILT_SAT] = (tilt_sat || lifted) ? 1.0 : 0.0;
    out[OUT_THRUST_SAT] = clipped != rel ? 1.0 : 0.0;
}

/* TiltReference.step toward (roll, pitch). */
static void tilt_step(const Params *P, State *S, double dt, const double *raw)
{
    double w = P->tilt_w;
    double nf = ceil(w * dt / 0.1 - 1e-9);
    long n = nf > 1.0 ? (long)nf : 1;
    double h = dt / (double)n;
    double w2 = w * w, w3 = w * w * w;
    for (long k = 0; k < n; ++k)
        for (int i = 0; i < 2; ++i) {
            double jerk = w3 * (raw[i] - S->tilt_x[i]) - 3.0 * w2 * S->tilt_v[i]
                          - 3.0 * w * S->tilt_a[i];
            S->tilt_a[i] += h * jerk;
            S->tilt_v[i] += h * S->tilt_a[i];
            S->tilt_x[i] += h * S->tilt_v[i];
        }
}

/* The estimator's inputs: the cycle's own, or those of an earlier cycle
 * (companion.estimation.inputs.DelayedInputs, kept by the caller). */
typedef struct {
    const double *q, *qd, *qdd, *tau;
    int skip;
} EstimatorInputs;

static int control_step(const Params *P, State *S, double dt, int skip, const double *q,
                        const double *qd, const double *qdd, const double *des_q,
                        const double *des_qd, const double *des_qdd, const double *tau_in,
                        const EstimatorInputs *est, double *out)
{
    double pieces[4 * PIECE], yt[32], y[NQ * 4], ysel_q[NQ], ysel_qd[NQ], tsel[NQ];
    int n = (int)P->n_rows;

    /* 1. model terms and the estimator's regressor Y(q, q_dot, q_dot, q_ddot), at the
     *    estimator's state if it is not this cycle's */
    const double *eq = q, *eqd = qd, *eqdd = qdd, *etau = tau_in;
    if (est) {
        eq = est->q;
        eqd = est->qd;
        eqdd = est->qdd;
        etau = est->tau;
        skip = est->skip;
        mcg_eval(eq, eqd, P->model, pieces);
        regress(pieces, eqd, eqdd, yt);
        mcg_eval(q, qd, P->model, pieces);
    } else {
        mcg_eval(q, qd, P->model, pieces);
        regress(pieces, qd, qdd, yt);
    }
    for (int r = 0; r < n; ++r) {
        int row = (int)P->rows[r];
        for (int k = 0; k < 4; ++k) y[4 * r + k] = yt[8 * k + row];
        ysel_q[r] = eq[row];
        ysel_qd[r] = eqd[row];
        tsel[r] = etau[row];
    }

    /* 2. estimator (_Base.update) and its publication */
    if (!S->frozen) {
        if (skip >= 0) {
            S->skipped[skip] += 1.0;
        } else {
            double st = 0.0, sy = 0.0;
            for (int r = 0; r < n; ++r) st += tsel[r];
            for (int i = 0; i < 4 * n; ++i) sy += y[i];
            if (isfinite(st) && isfinite(sy)) {
                int ok = P->rls ? rls_step(P, S, n, dt, y, tsel)
                                : paper_step(P, S, n, dt, y, ysel_q, ysel_qd, tsel);
                if (!ok) return 0;
            } else {
                S->skipped[3] += 1.0;
            }
        }
        if (S->calibrating) S->s_comp = S->thrust_scale;
    }
    monitor_update(P, S, dt, y, n);
    out[OUT_THETA] = S->theta[0];
    out[OUT_THETA + 1] = S->theta[1];
    out[OUT_THETA + 2] = S->theta[2];
    out[OUT_EXCITATION] = S->excitation;
    out[OUT_SPREAD] = S->spread;
    out[OUT_CONFIDENT] = (!S->frozen && S->excitation >= P->excitation_min
                          && S->spread <= P->spread_max) ? 1.0 : 0.0;
    if (out[OUT_CONFIDENT] == 1.0) S->scale_held = 0.0;
    out[OUT_FROZEN] = S->frozen;
    out[OUT_SCALE] = S->thrust_scale;

    /* 3. the tilt reference in the desired state */
    double *rq = out + OUT_REF_Q, *rqd = out + OUT_REF_QD, *rqdd = out + OUT_REF_QDD;
    for (int i = 0; i < NQ; ++i) {
        rq[i] = des_q[i];
        rqd[i] = des_qd[i];
        rqdd[i] = des_qdd[i];
    }
    for (int i = 0; i < 2; ++i) {
        rq[3 + i] = S->tilt_x[i];
        rqd[3 + i] = S->tilt_v[i];
        rqdd[3 + i] = S->tilt_a[i];
    }

    /* 4. eq. tau2, then the trim */
    double xi[4];
    for (int k = 0; k < 3; ++k) xi[k] = P->fixed ? P->fixed_xi[k] : S->theta[k];
    xi[3] = 1.0;
    for (int k = 0; k < 3; ++k) out[OUT_THETA_USED + k] = xi[k];
    double lqd[NQ], lqdd[NQ]; /* the law's q_dot, q_ddot: measured on unactuated rows */
    for (int i = 0; i < NQ; ++i) {
        lqd[i] = P->measured[i] ? qd[i] : rqd[i];
        lqdd[i] = P->measured[i] ? qdd[i] : rqdd[i];
    }
    regress(pieces, lqd, lqdd, yt);
    double *tau = out + OUT_TAU;
    for (int i = 0; i < NQ; ++i) {
        double ff = 0.0;
        for (int k = 0; k < 4; ++k) ff += yt[8 * k + i] * xi[k];
        double e = q[i] - rq[i];
        if (i == 5) e = wrap_pi(e);
        tau[i] = ff - P->k[i] * (qd[i] - lqd[i]) - P->k_lam[i] * e;
    }
    if (S->trim_active) {
        for (int i = 0; i < 2; ++i) {
            double sliding = (qd[i] - rqd[i]) + P->lam_xy[i] * (q[i] - rq[i]);
            double f = S->trim_force[i] - dt * P->trim_gain * sliding;
            S->trim_force[i] = py_min(py_max(f, -P->trim_limit), P->trim_limit);
        }
    }
    tau[0] += S->trim_force[0];
    tau[1] += S->trim_force[1];

    /* 5. setpoint (of the force over the calibrated s if compensated), then the tilt
     *    reference's step toward it */
    double force[3] = {tau[0], tau[1], tau[2]};
    if (P->compensate)
        for (int i = 0; i < 3; ++i) force[i] = tau[i] / S->s_comp;
    setpoint(P, force, q[5], rq[5], out);
    double raw[2] = {out[OUT_ROLL], out[OUT_PITCH]};
    tilt_step(P, S, dt, raw);

    /* 6. AttitudeLoopInverse.offset for (Mhat qd_ddot + Chat qd_dot + Ghat)[roll, pitch]
     *    with roll, pitch and their rates at the reference (FlightControl._attitude_offset),
     *    over the calibrated s if compensated */
    if (P->ff_on) {
        double fq[NQ], fqd[NQ];
        for (int i = 0; i < NQ; ++i) {
            fq[i] = (i == 3 || i == 4) ? rq[i] : q[i];
            fqd[i] = (i == 3 || i == 4) ? rqd[i] : qd[i];
        }
        mcg_eval(fq, fqd, P->model, pieces);
        regress(pieces, rqd, rqdd, yt);
        double alpha = dt / (P->ff_tf + dt);
        for (int i = 0; i < 2; ++i) {
            double torque = 0.0;
            for (int k = 0; k < 4; ++k) torque += yt[8 * k + 3 + i] * xi[k];
            if (P->compensate) torque = torque / S->s_comp;
            S->ff_torque_f[i] = S->ff_torque_f[i] + alpha * (torque - S->ff_torque_f[i]);
            double v = (S->ff_torque_f[i] / P->ff_torque[i] - S->ff_int[i]) / P->ff_rate_p[i];
            double e = py_min(py_max(v / P->ff_att_p[i], -P->ff_max[i]), P->ff_max[i]);
            v = P->ff_att_p[i] * e;
            double integral = S->ff_int[i] + P->ff_rate_i[i] * v * dt;
            S->ff_int[i] = py_min(py_max(integral, -P->ff_int_lim[i]), P->ff_int_lim[i]);
            out[OUT_ROLL + i] += e;
        }
    }
    return 1;
}

/* A C-contiguous buffer of native float64 values (n of them, or any number if n < 0;
 * writable if asked): TypeError on another element type (an int64 array of 8 values has
 * the length of 8 doubles), BufferError if not contiguous, ValueError on a wrong count. */
static int get_doubles(PyObject *obj, Py_buffer *b, Py_ssize_t n, const char *name,
                       int writable)
{
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, b, flags) < 0) return 0;
    const char *f = b->format ? b->format : "B";
    if (b->itemsize != (Py_ssize_t)sizeof(double)
        || !(strcmp(f, "d") == 0 || strcmp(f, "@d") == 0 || strcmp(f, "=d") == 0)) {
        PyErr_Format(PyExc_TypeError, "%s: expected float64 values, got format '%s'", name, f);
        PyBuffer_Release(b);
        return 0;
    }
    if (n >= 0 && b->len != n * (Py_ssize_t)sizeof(double)) {
        PyErr_Format(PyExc_ValueError, "%s: expected %zd float64 values, got %zd", name, n,
                     b->len / (Py_ssize_t)sizeof(double));
        PyBuffer_Release(b);
        return 0;
    }
    return 1;
}

#define N_STEP_BUFFERS 14
static PyObject *py_step(PyObject *self, PyObject *args)
{
    PyObject *obj[N_STEP_BUFFERS] = {NULL};
    Py_buffer b[N_STEP_BUFFERS];
    double dt;
    int skip, est_skip = -1, got = 0;
    static const char *names[N_STEP_BUFFERS] = {
        "params", "q", "q_dot", "q_ddot", "qd", "qd_dot", "qd_ddot", "tau", "out", "state",
        "est_q", "est_q_dot", "est_q_ddot", "est_tau"};
    if (!PyArg_ParseTuple(args, "OOdiOOOOOOOO|OOOOi", &obj[0], &obj[9], &dt, &skip, &obj[1],
                          &obj[2], &obj[3], &obj[4], &obj[5], &obj[6], &obj[7], &obj[8],
                          &obj[10], &obj[11], &obj[12], &obj[13], &est_skip))
        return NULL;
    int n_buffers = obj[10] ? N_STEP_BUFFERS : 10;
    PyObject *result = NULL;
    const Params *P = NULL;
    if (obj[10] && !(obj[11] && obj[12] && obj[13])) {
        PyErr_SetString(PyExc_TypeError, "the estimator's inputs come as q, q_dot, q_ddot, tau");
        return NULL;
    }
    for (; got < n_buffers; ++got) {
        Py_ssize_t n = got == 0 ? (Py_ssize_t)(sizeof(Params) / sizeof(double))
                       : got == 8 ? OUT_SIZE
                       : got == 9 ? (Py_ssize_t)(sizeof(State) / sizeof(double))
                                        + 2 * (Py_ssize_t)P->window_samples
                                  : NQ;
        if (!get_doubles(obj[got], &b[got], n, names[got], got == 8 || got == 9)) break;
        if (got == 0) P = (const Params *)b[0].buf;
    }
    EstimatorInputs est;
    if (n_buffers == N_STEP_BUFFERS && got == n_buffers)
        est = (EstimatorInputs){(const double *)b[10].buf, (const double *)b[11].buf,
                                (const double *)b[12].buf, (const double *)b[13].buf, est_skip};
    if (got < n_buffers) {
        /* error set */
    } else if (!(dt > 0.0)) {
        char msg[80];
        snprintf(msg, sizeof msg, "dt must be positive, got %.17g", dt);
        PyErr_SetString(PyExc_ValueError, msg);
    } else if (skip < -1 || skip >= N_SKIP || est_skip < -1 || est_skip >= N_SKIP) {
        PyErr_Format(PyExc_ValueError, "skip must lie in [-1, %d), got %d", N_SKIP,
                     skip < -1 || skip >= N_SKIP ? skip : est_skip);
    } else if (control_step(P, (State *)b[9].buf, dt, skip, (const double *)b[1].buf,
                            (const double *)b[2].buf, (const double *)b[3].buf,
                            (const double *)b[4].buf, (const double *)b[5].buf,
                            (const double *)b[6].buf, (const double *)b[7].buf,
                            n_buffers == N_STEP_BUFFERS ? &est : NULL, (double *)b[8].buf)) {
        result = Py_NewRef(Py_None);
    }
    for (int i = 0; i < got; ++i) PyBuffer_Release(&b[i]);
    return result;
}

/* StateFilter._fuse: one scalar Kalman update per column of the stacked filter state X
 * (17 x n, row-major; layout in companion/estimation/filters.py) with the (25 x 17) measurement
 * matrix G: W = G X; the innovation rows of the columns in `wrap` wrapped to [-pi, pi);
 * X[0:12] += (W[12:24] / W[24]) * W[0:12]. X is unchanged if W[0] is not finite. */
#define N_STACK 17
static double wrap_angle(double a)
{
    double w = py_mod(a + PI, 2.0 * PI) - PI;
    return w >= PI ? w - 2.0 * PI : w; /* (a + pi) % 2 pi can round up to 2 pi */
}

/* The scalar updates of every column (n of them) of X with G; 0 with an exception set (X
 * unchanged) if W[0] is not finite or a column of `wrap` is out of range. */
static int fuse_columns(double *X, Py_ssize_t n, const double *G, PyObject *wrap)
{
    double W[25 * NQ], total = 0.0;
    for (int i = 0; i < 25; ++i)
        for (Py_ssize_t c = 0; c < n; ++c) {
            double acc = 0.0;
            for (int k = 0; k < N_STACK; ++k) acc += G[N_STACK * i + k] * X[n * k + c];
            W[n * i + c] = acc;
        }
    for (Py_ssize_t c = 0; c < n; ++c) total += W[c];
    if (!isfinite(total)) {
        PyErr_SetString(PyExc_ValueError, "measurement or state is not finite");
        return 0;
    }
    for (Py_ssize_t j = 0; j < PyTuple_GET_SIZE(wrap); ++j) {
        Py_ssize_t c = PyLong_AsSsize_t(PyTuple_GET_ITEM(wrap, j));
        if (c < 0 || c >= n) {
            if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "wrap: column out of range");
            return 0;
        }
        double a = W[c];
        if (!(-PI <= a && a < PI)) W[c] = W[4 * n + c] = W[8 * n + c] = wrap_angle(a);
    }
    for (int i = 0; i < 3; ++i)
        for (int cc = 0; cc < 4; ++cc)
            for (Py_ssize_t c = 0; c < n; ++c) {
                double neg_k = W[n * (12 + 4 * i + cc) + c] / W[24 * n + c];
                X[n * (4 * i + cc) + c] += neg_k * W[n * (4 * i + cc) + c];
            }
    return 1;
}

static int stacked_columns(const Py_buffer *x, Py_ssize_t *n)
{
    *n = x->len / (Py_ssize_t)(N_STACK * sizeof(double));
    if (*n >= 1 && *n <= NQ && x->len == *n * N_STACK * (Py_ssize_t)sizeof(double)) return 1;
    PyErr_SetString(PyExc_ValueError, "X must hold 17 x n float64 values, 1 <= n <= 8");
    return 0;
}

static PyObject *py_fuse(PyObject *self, PyObject *args)
{
    Py_buffer g, x;
    PyObject *xo, *go, *wrap, *result = NULL;
    Py_ssize_t n;
    if (!PyArg_ParseTuple(args, "OOO!", &xo, &go, &PyTuple_Type, &wrap)) return NULL;
    if (!get_doubles(xo, &x, -1, "X", 1)) return NULL;
    if (!get_doubles(go, &g, 25 * N_STACK, "G", 0)) {
        PyBuffer_Release(&x);
        return NULL;
    }
    if (stacked_columns(&x, &n) && fuse_columns((double *)x.buf, n, (const double *)g.buf, wrap))
        result = Py_NewRef(Py_None);
    PyBuffer_Release(&g);
    PyBuffer_Release(&x);
    return result;
}

/* StateFilter._measurement_matrix: the (25 x 17) G of a measurement of derivative `order`
 * taken `latency` ago, its variance in stacked row `r_row` (the same values as the numpy
 * construction). */
#define X_Z 13
#define X_R_POS 14
#define X_R_CALL 16
#define R_UNMEASURED 1e150
static void measurement_matrix(int order, double latency, int r_row, double *G)
{
    double dt = -latency, h[3], v[4][N_STACK];
    if (order == 0) {
        h[0] = 1.0; h[1] = dt; h[2] = 0.5 * dt * dt;
    } else {
        h[0] = 0.0; h[1] = 1.0; h[2] = dt;
    }
    memset(v, 0, sizeof v);
    for (int i = 0; i < 3; ++i) v[0][4 * i] = h[i];
    v[0][X_Z] = -1.0;
    for (int j = 0; j < 3; ++j)
        for (int i = 0; i < 3; ++i) v[1 + j][4 * j + 1 + i] = h[i];
    memset(G, 0, 25 * N_STACK * sizeof(double));
    for (int i = 0; i < 3; ++i) {
        for (int r = 0; r < 4; ++r) {
            memcpy(G + N_STACK * (4 * i + r), v[r], sizeof v[r]);
            memcpy(G + N_STACK * (12 + 4 * i + r), v[1 + i], sizeof v[r]);
        }
        for (int j = 0; j < 3; ++j) G[N_STACK * 24 + 4 * i + 1 + j] = -h[i] * h[j];
    }
    G[N_STACK * 24 + r_row] = -1.0;
}

/* StateFilter._update's common case (default variance, every row initialised) in one call:
 * the measurement into X's row 13 on the measured columns, their default variance (row 14
 * + order) into row 16 and 1e150 elsewhere unless every column is measured in order, G,
 * and the scalar updates. On a non-finite measurement or state, or a bad latency, X's
 * row 13 is zeroed (as the reference's) and ValueError raised. */
static PyObject *py_update(PyObject *self, PyObject *args)
{
    PyObject *xo, *rows, *zo, *wrap, *zseq = NULL, *result = NULL;
    int order;
    double latency, z[NQ], G[25 * N_STACK];
    Py_buffer x;
    Py_ssize_t n, k;
    if (!PyArg_ParseTuple(args, "OidO!OO!", &xo, &order, &latency, &PyTuple_Type, &rows, &zo,
                          &PyTuple_Type, &wrap))
        return NULL;
    if (order != 0 && order != 1) {
        PyErr_SetString(PyExc_ValueError, "order must be 0 or 1");
        return NULL;
    }
    if (!get_doubles(xo, &x, -1, "X", 1)) return NULL;
    if (!stacked_columns(&x, &n)) goto done;
    k = PyTuple_GET_SIZE(rows);
    zseq = PySequence_Fast(zo, "");
    if (!zseq) goto not_numbers;
    if (k < 1 || k > n || PySequence_Fast_GET_SIZE(zseq) != k) {
        PyErr_Format(PyExc_ValueError, "measurement must have shape (%zd,), got %zd values", k,
                     PySequence_Fast_GET_SIZE(zseq));
        goto done;
    }
    int col[NQ], measured[NQ] = {0}, in_order = (k == n);
    for (Py_ssize_t i = 0; i < k; ++i) {
        Py_ssize_t c = PyLong_AsSsize_t(PyTuple_GET_ITEM(rows, i));
        if (c < 0 || c >= n || measured[c]) {
            if (!PyErr_Occurred())
                PyErr_SetString(PyExc_ValueError, "rows must lie in [0, n) and not repeat");
            goto done;
        }
        z[i] = PyFloat_AsDouble(PySequence_Fast_GET_ITEM(zseq, i));
        if (z[i] == -1.0 && PyErr_Occurred()) goto not_numbers;
        col[i] = (int)c;
        measured[c] = 1;
        in_order = in_order && c == i;
    }
    double *X = (double *)x.buf;
    for (Py_ssize_t i = 0; i < k; ++i) X[n * X_Z + col[i]] = z[i];
    int r_row = X_R_POS + order;
    if (!in_order) {
        for (Py_ssize_t c = 0; c < n; ++c)
            X[n * X_R_CALL + c] = measured[c] ? X[n * (X_R_POS + order) + c] : R_UNMEASURED;
        r_row = X_R_CALL;
    }
    if (!(isfinite(latency) && latency >= 0.0)) {
        PyErr_Format(PyExc_ValueError, "latency_s must be finite and >= 0, got %R",
                     PyTuple_GET_ITEM(args, 2));
    } else {
        measurement_matrix(order, latency, r_row, G);
        if (fuse_columns(X, n, G, wrap)) result = Py_NewRef(Py_None);
    }
    if (!result)
        for (Py_ssize_t c = 0; c < n; ++c) X[n * X_Z + c] = 0.0;
    goto done;
not_numbers: /* ValueError, as numpy's conversion in the reference */
    PyErr_Clear();
    PyErr_SetString(PyExc_ValueError, "the measurement must be a sequence of numbers");
done:
    Py_XDECREF(zseq);
    PyBuffer_Release(&x);
    return result;
}

/* StateFilter.predict's product: X_next = A X (A 17 x 17, X and X_next 17 x n). */
static PyObject *py_predict(PyObject *self, PyObject *args)
{
    PyObject *ao, *xo, *yo, *result = NULL;
    Py_buffer a, x, y;
    if (!PyArg_ParseTuple(args, "OOO", &ao, &xo, &yo)) return NULL;
    if (!get_doubles(ao, &a, N_STACK * N_STACK, "A", 0)) return NULL;
    if (!get_doubles(xo, &x, -1, "X", 0)) {
        PyBuffer_Release(&a);
        return NULL;
    }
    if (!get_doubles(yo, &y, x.len / (Py_ssize_t)sizeof(double), "X_next", 1)) {
        PyBuffer_Release(&a);
        PyBuffer_Release(&x);
        return NULL;
    }
    Py_ssize_t n;
    int ok = stacked_columns(&x, &n);
    if (ok && x.buf == y.buf) {
        PyErr_SetString(PyExc_ValueError, "X_next must not be X");
        ok = 0;
    }
    if (ok) {
        const double *A = (const double *)a.buf, *X = (const double *)x.buf;
        double *Y = (double *)y.buf;
        for (int i = 0; i < N_STACK; ++i)
            for (Py_ssize_t c = 0; c < n; ++c) {
                double acc = 0.0;
                for (int k = 0; k < N_STACK; ++k) acc += A[N_STACK * i + k] * X[n * k + c];
                Y[n * i + c] = acc;
            }
        result = Py_NewRef(Py_None);
    }
    PyBuffer_Release(&a);
    PyBuffer_Release(&x);
    PyBuffer_Release(&y);
    return result;
}

static PyMethodDef methods[] = {
    {"step", py_step, METH_VARARGS,
     "step(params, state, dt, skip, q, q_dot, q_ddot, qd, qd_dot, qd_ddot, tau, out): one "
     "control step; skip is -1 or the index of the Skip reason."},
    {"predict", py_predict, METH_VARARGS,
     "predict(A, X, X_next): the state filter's prediction product X_next = A X."},
    {"fuse", py_fuse, METH_VARARGS,
     "fuse(X, G, wrap): the state filter's scalar updates of every column of X, in place."},
    {"update", py_update, METH_VARARGS,
     "update(X, order, latency_s, rows, z, wrap): the state filter's update with the "
     "default variance, in place (G built here)."},
    {NULL, NULL, 0, NULL}
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_step", "The companion's control step in C (see _step.c).", -1,
    methods
};

static int add_offsets(PyObject *m)
{
    PyObject *layout = PyDict_New();
    if (!layout) return -1;
#define FIELD(type, f, n) \
    do { \
        PyObject *v = Py_BuildValue("(nn)", (Py_ssize_t)(offsetof(type, f) / sizeof(double)), \
                                    (Py_ssize_t)(n)); \
        if (!v || PyDict_SetItemString(layout, #type "." #f, v) < 0) { \
            Py_XDECREF(v); Py_DECREF(layout); return -1; \
        } \
        Py_DECREF(v); \
    } while (0)
    FIELD(Params, model, 14); FIELD(Params, rls, 1); FIELD(Params, has_scale, 1);
    FIELD(Params, measured, NQ); FIELD(Params, com_from_joints, 1);
    FIELD(Params, n_rows, 1); FIELD(Params, rows, NQ); FIELD(Params, yaw_index, 1);
    FIELD(Params, fixed, 1); FIELD(Params, fixed_xi, 4); FIELD(Params, k, NQ);
    FIELD(Params, k_lam, NQ); FIELD(Params, lam_xy, 2); FIELD(Params, gamma, 3);
    FIELD(Params, c_star, NQ); FIELD(Params, k_star, NQ); FIELD(Params, qhat_dot0, NQ);
    FIELD(Params, m2_min, 1); FIELD(Params, m2_max, 1); FIELD(Params, l2, 1);
    FIELD(Params, s_initial, 1); FIELD(Params, s_low, 1); FIELD(Params, s_high, 1);
    FIELD(Params, s_gamma, 1); FIELD(Params, s_drift2, 1); FIELD(Params, s_var_max, 1);
    FIELD(Params, forgetting, 1); FIELD(Params, p_trace_max, 1); FIELD(Params, p0, 9);
    FIELD(Params, r_forgotten, NQ); FIELD(Params, window_s, 1);
    FIELD(Params, sample_period_s, 1); FIELD(Params, excitation_min, 1);
    FIELD(Params, spread_max, 1); FIELD(Params, window_samples, 1);
    FIELD(Params, weight, 3 * NQ); FIELD(Params, tilt_w, 1); FIELD(Params, tilt_max, 1);
    FIELD(Params, thrust_max, 1); FIELD(Params, thrust_min_rel, 1); FIELD(Params, compensate, 1);
    FIELD(Params, trim_gain, 1); FIELD(Params, trim_limit, 1);
    FIELD(Params, ff_on, 1); FIELD(Params, ff_att_p, 2); FIELD(Params, ff_rate_p, 2);
    FIELD(Params, ff_rate_i, 2); FIELD(Params, ff_int_lim, 2); FIELD(Params, ff_torque, 2);
    FIELD(Params, ff_max, 2); FIELD(Params, ff_tf, 1);
    FIELD(State, theta, 3); FIELD(State, frozen, 1); FIELD(State, thrust_scale, 1);
    FIELD(State, scale_held, 1); FIELD(State, calibrating, 1); FIELD(State, s_comp, 1);
    FIELD(State, skipped, N_SKIP); FIELD(State, qhat_valid, 1); FIELD(State, qhat, NQ);
    FIELD(State, p, 9); FIELD(State, p_s, 3); FIELD(State, var_s, 1); FIELD(State, info, 9);
    FIELD(State, excitation, 1); FIELD(State, spread, 1); FIELD(State, since_sample, 1);
    FIELD(State, samples, 1); FIELD(State, ring_len, 1); FIELD(State, ring_head, 1);
    FIELD(State, tilt_x, 2); FIELD(State, tilt_v, 2); FIELD(State, tilt_a, 2);
    FIELD(State, trim_force, 2); FIELD(State, trim_active, 1); FIELD(State, ff_int, 2);
    FIELD(State, ff_torque_f, 2);
    FIELD(State, ring, 0);
#undef FIELD
    if (PyModule_AddIntConstant(m, "PARAMS_SIZE", sizeof(Params) / sizeof(double)) < 0
        || PyModule_AddIntConstant(m, "STATE_SIZE", sizeof(State) / sizeof(double)) < 0
        || PyModule_AddIntConstant(m, "OUT_SIZE", OUT_SIZE) < 0
        || PyModule_AddObject(m, "LAYOUT", layout) < 0) {
        Py_DECREF(layout);
        return -1;
    }
    return 0;
}

PyMODINIT_FUNC PyInit__step(void)
{
    PyObject *m = PyModule_Create(&module);
    if (m && add_offsets(m) < 0) Py_CLEAR(m);
    return m;
}
