/* Compiled per-step arithmetic of the SITL truth plant (sitl.physics).
 *
 * The same operations, in the same order, as the Python they replace or mirror, so that the
 * results agree to the last bit or close to it (built without floating-point contraction):
 *
 * step(...)        one step of sitl.physics.integration.ArticulatedIntegrator (semi-implicit
 *                  Euler or RK4 on the configuration manifold) under a GeneralizedForce or a
 *                  BodyWrench, the accelerations by Pinocchio's own compiled ABA (called back,
 *                  never re-implemented here), then the plant's kinematics of the new state
 *                  (TruthPlant._update_kinematics) and the step's q_ddot (_to_q_ddot).
 * kinematics(...)  the plant's kinematics of a state alone (after reset, hold, payload).
 * pack(...)       a state's floats as the bytes of one float64 array (PlantState).
 *
 * Independent of companion.model (DESIGN.md section 6): nothing here knows the arm's
 * dynamics, which stay Pinocchio's. Frames and units as in the Python modules: world ENU,
 * body FLU, quaternions [w, x, y, z] body to world (Pinocchio's configuration stores x, y,
 * z, w), SI units.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>

#define COS_THETA_MIN 1e-6
#define TWO_PI (2.0 * 3.141592653589793)

enum { OK = 0, DIVERGED = 1, SINGULAR = 2 };

/* ------------------------------------------------------------------ small helpers */

static int read_doubles(PyObject *seq, double *out, Py_ssize_t n, const char *name)
{
    PyObject *fast = PySequence_Fast(seq, name);
    if (fast == NULL) return 0;
    if (PySequence_Fast_GET_SIZE(fast) != n) {
        PyErr_Format(PyExc_ValueError, "%s: expected %zd values", name, n);
        Py_DECREF(fast);
        return 0;
    }
    PyObject **items = PySequence_Fast_ITEMS(fast);
    for (Py_ssize_t i = 0; i < n; i++) {
        out[i] = PyFloat_AsDouble(items[i]);
        if (out[i] == -1.0 && PyErr_Occurred()) {
            Py_DECREF(fast);
            return 0;
        }
    }
    Py_DECREF(fast);
    return 1;
}

static int read_buffer(PyObject *obj, double *out, Py_ssize_t n, const char *name)
{
    Py_buffer view;
    if (PyObject_GetBuffer(obj, &view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0) return 0;
    int ok = view.len == n * (Py_ssize_t)sizeof(double) && view.format != NULL
             && strcmp(view.format, "d") == 0;
    if (ok)
        memcpy(out, view.buf, (size_t)n * sizeof(double));
    else
        PyErr_Format(PyExc_ValueError, "%s: expected %zd float64 values", name, n);
    PyBuffer_Release(&view);
    return ok;
}

static int write_buffer(PyObject *obj, const double *values, Py_ssize_t n, const char *name)
{
    Py_buffer view;
    if (PyObject_GetBuffer(obj, &view, PyBUF_C_CONTIGUOUS | PyBUF_WRITABLE | PyBUF_FORMAT) < 0)
        return 0;
    int ok = view.len == n * (Py_ssize_t)sizeof(double) && view.format != NULL
             && strcmp(view.format, "d") == 0;
    if (ok)
        memcpy(view.buf, values, (size_t)n * sizeof(double));
    else
        PyErr_Format(PyExc_ValueError, "%s: expected %zd writable float64 values", name, n);
    PyBuffer_Release(&view);
    return ok;
}

static PyObject *new_list(const double *values, Py_ssize_t n)
{
    PyObject *list = PyList_New(n);
    if (list == NULL) return NULL;
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *f = PyFloat_FromDouble(values[i]);
        if (f == NULL) {
            Py_DECREF(list);
            return NULL;
        }
        PyList_SET_ITEM(list, i, f);
    }
    return list;
}

static PyObject *new_tuple(const double *values, Py_ssize_t n)
{
    PyObject *tuple = PyTuple_New(n);
    if (tuple == NULL) return NULL;
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *f = PyFloat_FromDouble(values[i]);
        if (f == NULL) {
            Py_DECREF(tuple);
            return NULL;
        }
        PyTuple_SET_ITEM(tuple, i, f);
    }
    return tuple;
}

/* ------------------------------------------------------------------ frames (frames.py) */

static void rotation9(double w, double x, double y, double z, double *r)
{
    r[0] = 1.0 - 2.0 * (y * y + z * z);
    r[1] = 2.0 * (x * y - w * z);
    r[2] = 2.0 * (x * z + w * y);
    r[3] = 2.0 * (x * y + w * z);
    r[4] = 1.0 - 2.0 * (x * x + z * z);
    r[5] = 2.0 * (y * z - w * x);
    r[6] = 2.0 * (x * z - w * y);
    r[7] = 2.0 * (y * z + w * x);
    r[8] = 1.0 - 2.0 * (x * x + y * y);
}

static double clamp_unit(double v)
{
    /* Python's max(-1.0, min(1.0, v)) */
    double m = v < 1.0 ? v : 1.0;
    return m > -1.0 ? m : -1.0;
}

/* W(Phi)^-1 row-major; SINGULAR when |cos(theta)| < COS_THETA_MIN. */
static int euler_rate_inverse9(double phi, double theta, double *wi)
{
    double ct = cos(theta);
    if (fabs(ct) < COS_THETA_MIN) return SINGULAR;
    double cf = cos(phi), sf = sin(phi);
    double tt = sin(theta) / ct;
    wi[0] = 1.0; wi[1] = sf * tt; wi[2] = cf * tt;
    wi[3] = 0.0; wi[4] = cf; wi[5] = -sf;
    wi[6] = 0.0; wi[7] = sf / ct; wi[8] = cf / ct;
    return OK;
}

/* ------------------------------------------------------------------ integration.py */

typedef struct {
    int kind;        /* 0: GeneralizedForce (tau conjugate to q), 1: BodyWrench */
    double v[12];    /* tau (8) | thrust, torque (3), drag (3), joint torques (2), wind (3) */
} Force;

typedef struct {
    PyObject *aba, *model, *data, *q, *v, *tau;
    double theta;    /* the pitch of a SINGULAR result */
} Dynamics;

static int force_eval(const Force *f, const double *r, const double *u, double *out,
                      double *theta_out)
{
    if (f->kind == 0) {
        double phi = atan2(r[7], r[8]);
        double theta = asin(clamp_unit(-r[6]));
        double wi[9];
        if (euler_rate_inverse9(phi, theta, wi) != OK) {
            *theta_out = theta;
            return SINGULAR;
        }
        const double *t = f->v;
        double fx = t[0], fy = t[1], fz = t[2], tp = t[3], tt = t[4], ts = t[5];
        out[0] = r[0] * fx + r[3] * fy + r[6] * fz;
        out[1] = r[1] * fx + r[4] * fy + r[7] * fz;
        out[2] = r[2] * fx + r[5] * fy + r[8] * fz;
        out[3] = tp;
        out[4] = wi[1] * tp + wi[4] * tt + wi[7] * ts;
        out[5] = wi[2] * tp + wi[5] * tt + wi[8] * ts;
        out[6] = t[6];
        out[7] = t[7];
        return OK;
    }
    const double *b = f->v;
    double fx = -b[4] * (u[0] - b[9]), fy = -b[5] * (u[1] - b[10]);
    double fz = -b[6] * (u[2] - b[11]);
    out[0] = r[0] * fx + r[3] * fy + r[6] * fz;
    out[1] = r[1] * fx + r[4] * fy + r[7] * fz;
    out[2] = r[2] * fx + r[5] * fy + r[8] * fz + b[0];
    out[3] = b[1];
    out[4] = b[2];
    out[5] = b[3];
    out[6] = b[7];
    out[7] = b[8];
    return OK;
}

/* Pinocchio's ABA on (q, v, tau) through the Python binding; -1 with an exception set. */
static int call_aba(Dynamics *d, const double *q, const double *v, const double *tau,
                    double *a)
{
    if (!write_buffer(d->q, q, 9, "q") || !write_buffer(d->v, v, 8, "v")
        || !write_buffer(d->tau, tau, 8, "tau"))
        return -1;
    PyObject *args[5] = {d->model, d->data, d->q, d->v, d->tau};
    PyObject *result = PyObject_Vectorcall(d->aba, args, 5, NULL);
    if (result == NULL) return -1;
    int ok = read_buffer(result, a, 8, "aba");
    Py_DECREF(result);
    return ok ? 0 : -1;
}

/* du/dt = [p_ddot (world), omega_dot (body), eta_ddot] (ArticulatedIntegrator.accelerations).
 * Returns OK, DIVERGED, SINGULAR, or -1 with a Python exception set. */
static int accelerations(Dynamics *d, const double *x, const double *u, const Force *f,
                         const double *r_known, double *k)
{
    double r[9], v[8], tau[8], a[8];
    if (r_known != NULL)
        memcpy(r, r_known, sizeof r);
    else
        rotation9(x[6], x[3], x[4], x[5], r);
    double fx = u[0], fy = u[1], fz = u[2];
    v[0] = r[0] * fx + r[3] * fy + r[6] * fz;
    v[1] = r[1] * fx + r[4] * fy + r[7] * fz;
    v[2] = r[2] * fx + r[5] * fy + r[8] * fz;
    for (int i = 3; i < 8; i++) v[i] = u[i];
    int status = force_eval(f, r, u, tau, &d->theta);
    if (status != OK) return status;
    if (call_aba(d, x, v, tau, a) < 0) return -1;
    double sum = 0.0;
    for (int i = 0; i < 8; i++) sum += a[i];
    if (!isfinite(sum)) return DIVERGED;
    double ox = u[3], oy = u[4], oz = u[5];
    double bx = a[0] + oy * v[2] - oz * v[1];
    double by = a[1] + oz * v[0] - ox * v[2];
    double bz = a[2] + ox * v[1] - oy * v[0];
    k[0] = r[0] * bx + r[1] * by + r[2] * bz;
    k[1] = r[3] * bx + r[4] * by + r[5] * bz;
    k[2] = r[6] * bx + r[7] * by + r[8] * bz;
    for (int i = 3; i < 8; i++) k[i] = a[i];
    return OK;
}

/* x (+) h u (integration.retract); DIVERGED on a non-finite body rate. */
static int retract(const double *x, const double *u, double h, double *out)
{
    double px = x[0], py = x[1], pz = x[2], qx = x[3], qy = x[4], qz = x[5], qw = x[6];
    double hx = 0.5 * h * u[3], hy = 0.5 * h * u[4], hz = 0.5 * h * u[5];
    double half = sqrt(hx * hx + hy * hy + hz * hz);
    if (!isfinite(half)) return DIVERGED;
    double c, k;
    if (half > 1e-8) {
        c = cos(half);
        k = sin(half) / half;
    } else {
        c = 1.0 - 0.5 * half * half;
        k = 1.0 - half * half / 6.0;
    }
    hx = k * hx; hy = k * hy; hz = k * hz;
    out[0] = px + h * u[0];
    out[1] = py + h * u[1];
    out[2] = pz + h * u[2];
    out[3] = qw * hx + qx * c + qy * hz - qz * hy;
    out[4] = qw * hy - qx * hz + qy * c + qz * hx;
    out[5] = qw * hz + qx * hy - qy * hx + qz * c;
    out[6] = qw * c - qx * hx - qy * hy - qz * hz;
    out[7] = x[7] + h * u[6];
    out[8] = x[8] + h * u[7];
    return OK;
}

static int integrate(Dynamics *d, int rk4, double dt, const double *x, const double *u,
                     const double *r, const Force *f, double *x_new, double *u_new, double *k1)
{
    int s = accelerations(d, x, u, f, r, k1);
    if (s != OK) return s;
    if (!rk4) {
        for (int i = 0; i < 8; i++) u_new[i] = u[i] + dt * k1[i];
        return retract(x, u_new, dt, x_new);
    }
    double h = 0.5 * dt, xs[9], u2[8], u3[8], u4[8], k2[8], k3[8], k4[8], mean[8];
    for (int i = 0; i < 8; i++) u2[i] = u[i] + h * k1[i];
    if ((s = retract(x, u, h, xs)) != OK || (s = accelerations(d, xs, u2, f, NULL, k2)) != OK)
        return s;
    for (int i = 0; i < 8; i++) u3[i] = u[i] + h * k2[i];
    if ((s = retract(x, u2, h, xs)) != OK || (s = accelerations(d, xs, u3, f, NULL, k3)) != OK)
        return s;
    for (int i = 0; i < 8; i++) u4[i] = u[i] + dt * k3[i];
    if ((s = retract(x, u3, dt, xs)) != OK || (s = accelerations(d, xs, u4, f, NULL, k4)) != OK)
        return s;
    double sixth = dt / 6.0;
    for (int i = 0; i < 8; i++) {
        u_new[i] = u[i] + sixth * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
        mean[i] = (u[i] + 2.0 * u2[i] + 2.0 * u3[i] + u4[i]) / 6.0;
    }
    return retract(x, mean, dt, x_new);
}

/* ------------------------------------------------------------------ plant.py kinematics */

typedef struct {
    double x[9], u[8];       /* x with the quaternion renormalized */
    double quat[4], r[9], euler[3], wi[9], omega[3], q[8], qd[8];
} Kinematics;

/* TruthPlant._update_kinematics: DIVERGED (non-finite state) or SINGULAR (theta). */
static int kinematics(const double *x, const double *u, const double *euler_prev,
                      Kinematics *out, double *theta_out)
{
    double sum = 0.0;
    for (int i = 0; i < 9; i++) sum += x[i];
    double sum_u = 0.0;
    for (int i = 0; i < 8; i++) sum_u += u[i];
    if (!isfinite(sum + sum_u)) return DIVERGED;
    double qx = x[3], qy = x[4], qz = x[5], qw = x[6];
    double n = sqrt(qx * qx + qy * qy + qz * qz + qw * qw);
    if (qw < 0.0) n = -n;
    qx = qx / n; qy = qy / n; qz = qz / n; qw = qw / n;
    memcpy(out->x, x, sizeof out->x);
    out->x[3] = qx; out->x[4] = qy; out->x[5] = qz; out->x[6] = qw;
    memcpy(out->u, u, sizeof out->u);
    out->quat[0] = qw; out->quat[1] = qx; out->quat[2] = qy; out->quat[3] = qz;
    double *r = out->r;
    rotation9(qw, qx, qy, qz, r);
    double phi = atan2(r[7], r[8]);
    double theta = asin(clamp_unit(-r[6]));
    double psi = atan2(r[3], r[0]);
    phi += TWO_PI * nearbyint((euler_prev[0] - phi) / TWO_PI);
    psi += TWO_PI * nearbyint((euler_prev[2] - psi) / TWO_PI);
    out->euler[0] = phi; out->euler[1] = theta; out->euler[2] = psi;
    double *wi = out->wi;
    if (euler_rate_inverse9(phi, theta, wi) != OK) {
        *theta_out = theta;
        return SINGULAR;
    }
    double ox = u[3], oy = u[4], oz = u[5];
    out->omega[0] = ox; out->omega[1] = oy; out->omega[2] = oz;
    double q[8] = {x[0], x[1], x[2], phi, theta, psi, x[7], x[8]};
    memcpy(out->q, q, sizeof q);
    out->qd[0] = u[0];
    out->qd[1] = u[1];
    out->qd[2] = u[2];
    out->qd[3] = ox + wi[1] * oy + wi[2] * oz;
    out->qd[4] = wi[4] * oy + wi[5] * oz;
    out->qd[5] = wi[7] * oy + wi[8] * oz;
    out->qd[6] = u[6];
    out->qd[7] = u[7];
    return OK;
}

/* TruthPlant._to_q_ddot: our q_ddot from du/dt at the state (euler, euler rates, W^-1). */
static void q_ddot(const double *k, const double *euler, const double *qd, const double *wi,
                   double *out)
{
    double phi = euler[0], theta = euler[1];
    double pd = qd[3], td = qd[4], sd = qd[5];
    double cf = cos(phi), sf = sin(phi), ct = cos(theta), st = sin(theta);
    double c0 = -ct * td * sd;
    double c1 = -sf * pd * td + (cf * ct * pd - sf * st * td) * sd;
    double c2 = -cf * pd * td - (sf * ct * pd + cf * st * td) * sd;
    double d0 = k[3] - c0, d1 = k[4] - c1, d2 = k[5] - c2;
    out[0] = k[0]; out[1] = k[1]; out[2] = k[2];
    out[3] = d0 + wi[1] * d1 + wi[2] * d2;
    out[4] = wi[4] * d1 + wi[5] * d2;
    out[5] = wi[7] * d1 + wi[8] * d2;
    out[6] = k[6]; out[7] = k[7];
}

/* (x, u, quat, R9, euler, W^-1, omega, q, q_dot) as Python objects, in that order. */
static PyObject *kinematics_tuple(const Kinematics *k, const double *qdd)
{
    PyObject *items[11];
    int n = 0;
    items[n++] = new_list(k->x, 9);
    items[n++] = new_list(k->u, 8);
    if (qdd != NULL) items[n++] = new_list(qdd, 8);
    items[n++] = new_tuple(k->quat, 4);
    items[n++] = new_tuple(k->r, 9);
    items[n++] = new_tuple(k->euler, 3);
    items[n++] = new_tuple(k->wi, 9);
    items[n++] = new_tuple(k->omega, 3);
    items[n++] = new_list(k->q, 8);
    items[n++] = new_list(k->qd, 8);
    PyObject *tuple = PyTuple_New(n + 1);
    int ok = tuple != NULL;
    for (int i = 0; i < n; i++) ok = ok && items[i] != NULL;
    if (!ok) {
        for (int i = 0; i < n; i++) Py_XDECREF(items[i]);
        Py_XDECREF(tuple);
        return NULL;
    }
    PyTuple_SET_ITEM(tuple, 0, PyLong_FromLong(OK));
    for (int i = 0; i < n; i++) PyTuple_SET_ITEM(tuple, i + 1, items[i]);
    return tuple;
}

static PyObject *failure(int status, double theta)
{
    return Py_BuildValue("(id)", status, theta);
}

static PyObject *py_kinematics(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    double x[9], u[8], euler[3], theta = 0.0;
    if (nargs != 3) {
        PyErr_SetString(PyExc_TypeError, "kinematics(x, u, euler_previous)");
        return NULL;
    }
    if (!read_doubles(args[0], x, 9, "x") || !read_doubles(args[1], u, 8, "u")
        || !read_doubles(args[2], euler, 3, "euler_previous"))
        return NULL;
    Kinematics k;
    int s = kinematics(x, u, euler, &k, &theta);
    if (s != OK) return failure(s, theta);
    return kinematics_tuple(&k, NULL);
}

static PyObject *py_step(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 16) {
        PyErr_SetString(PyExc_TypeError,
                        "step(rk4, dt, x, u, r9, euler, q_dot, w_inv9, kind, force, aba, model,"
                        " data, q, v, tau)");
        return NULL;
    }
    double x[9], u[8], r[9], euler[3], qd[8], wi[9];
    Force f;
    int rk4 = PyObject_IsTrue(args[0]);
    double dt = PyFloat_AsDouble(args[1]);
    f.kind = (int)PyLong_AsLong(args[8]);
    if (rk4 < 0 || PyErr_Occurred()) return NULL;
    if (!read_doubles(args[2], x, 9, "x") || !read_doubles(args[3], u, 8, "u")
        || !read_doubles(args[4], r, 9, "r9") || !read_doubles(args[5], euler, 3, "euler")
        || !read_doubles(args[6], qd, 8, "q_dot") || !read_doubles(args[7], wi, 9, "w_inv9")
        || !read_doubles(args[9], f.v, f.kind == 0 ? 8 : 12, "force"))
        return NULL;
    Dynamics d = {args[10], args[11], args[12], args[13], args[14], args[15], 0.0};
    double x_new[9], u_new[8], k1[8], qdd[8];
    int s = integrate(&d, rk4, dt, x, u, r, &f, x_new, u_new, k1);
    if (s < 0) return NULL;
    if (s != OK) return failure(s, d.theta);
    q_ddot(k1, euler, qd, wi, qdd);
    Kinematics k;
    double theta = 0.0;
    /* kinematics of the new state: a failure there comes after the step (the caller commits
       x and u first, as the Python did) */
    s = kinematics(x_new, u_new, euler, &k, &theta);
    if (s != OK) {
        PyObject *xs = new_list(x_new, 9), *us = new_list(u_new, 8), *qs = new_list(qdd, 8);
        if (xs == NULL || us == NULL || qs == NULL) {
            Py_XDECREF(xs); Py_XDECREF(us); Py_XDECREF(qs);
            return NULL;
        }
        return Py_BuildValue("(idNNN)", s + 2, theta, xs, us, qs);
    }
    return kinematics_tuple(&k, qdd);
}

/* The doubles of the given sequences, in order, as one bytes object (a frozen state's
 * storage: numpy reads it in place, read-only). */
static PyObject *py_pack(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    double values[64];
    Py_ssize_t n = 0;
    for (Py_ssize_t a = 0; a < nargs; a++) {
        PyObject *fast = PySequence_Fast(args[a], "pack: sequences of floats");
        if (fast == NULL) return NULL;
        Py_ssize_t size = PySequence_Fast_GET_SIZE(fast);
        if (n + size > 64) {
            Py_DECREF(fast);
            PyErr_SetString(PyExc_ValueError, "pack: more than 64 values");
            return NULL;
        }
        PyObject **items = PySequence_Fast_ITEMS(fast);
        for (Py_ssize_t i = 0; i < size; i++) {
            double v = PyFloat_AsDouble(items[i]);
            if (v == -1.0 && PyErr_Occurred()) {
                Py_DECREF(fast);
                return NULL;
            }
            values[n++] = v;
        }
        Py_DECREF(fast);
    }
    return PyBytes_FromStringAndSize((const char *)values, n * (Py_ssize_t)sizeof(double));
}

static PyMethodDef methods[] = {
    {"pack", (PyCFunction)(void (*)(void))py_pack, METH_FASTCALL,
     "pack(*sequences): their floats as the bytes of float64 values."},
    {"step", (PyCFunction)(void (*)(void))py_step, METH_FASTCALL,
     "step(rk4, dt, x, u, r9, euler, q_dot, w_inv9, kind, force, aba, model, data, q, v, tau):"
     " one integration step and the new state's kinematics."},
    {"kinematics", (PyCFunction)(void (*)(void))py_kinematics, METH_FASTCALL,
     "kinematics(x, u, euler_previous): the plant's kinematics of a state."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_kernel", "Compiled per-step arithmetic of the SITL truth plant.",
    -1, methods,
};

PyMODINIT_FUNC PyInit__kernel(void) { return PyModule_Create(&module); }
