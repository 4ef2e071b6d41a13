"""Symbolic derivation of the hexacopter + 2-DOF arm dynamics; writes the C source ``_mcg.c``
and the C type of its capsule, ``mcg_eval.pxd``.

Run ``python -m companion.model.derive`` to regenerate, ``--check`` to verify that the
committed file is what this derivation produces (the test suite does). Needs sympy
(the ``test`` extra), which the runtime package does not import. The C file is compiled
into the extension module ``companion.model._mcg`` when the package is installed: the
same expressions evaluated in Python took about 170 us a state, in C about 3 us.

Model (paper section II, DESIGN.md sections 2-3)
-----------------------------------------------
q = [x, y, z, phi, theta, psi, eta1, eta2]; p = (x, y, z) is the vehicle CoM in the ENU
world frame, R = Rz(psi) Ry(theta) Rx(phi) maps FLU body vectors to the world, and the body
angular velocity is omega_B = vee(R^T R_dot). Joint 1 sits at body point r_a; both joint
axes are parallel to body y, the links point along u1 = (cos eta1, 0, sin eta1) and
u2 = (cos(eta1 + eta2), 0, sin(eta1 + eta2)).

Each link is a mass distribution on its own axis, so with the body-frame velocity of its
points A + s B (s: distance from the joint) the kinetic energy is
1/2 (m |A|^2 + 2 s1 A.B + J |B|^2): exactly linear in (mass m, first moment s1, second
moment J). For link 2 these are the unknowns (m2, m3, m4). Servo armature a_i adds
1/2 a_i eta_i_dot^2. Then M = hessian(T, q_dot), C from the Christoffel symbols of the first
kind (so M_dot - 2 C is skew-symmetric), G = dV/dq, and each is split into the known part
and the coefficients of m2, m3, m4 (eq. mcg_param).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from companion.model.layout import PARAM_NAMES, XI_ORDER

TARGET = Path(__file__).with_name("_mcg.c")
PXD_TARGET = Path(__file__).with_name("mcg_eval.pxd")
"""The C type of the capsule ``_mcg.mcg_eval``, for Cython code that calls it."""
CAPSULE = "companion.model._mcg.mcg_eval"


def derive():
    """Return (q, qd, params, theta, M, C, G, V) as sympy objects."""
    import sympy as sp

    q = sp.symbols("x y z phi theta psi eta1 eta2", real=True)
    qd = sp.symbols("xd yd zd phid thetad psid eta1d eta2d", real=True)
    params = sp.symbols(" ".join(PARAM_NAMES), real=True)
    mb, ixx, iyy, izz, m1, s1, j1, a1, a2, l1, rax, ray, raz, g = params
    theta = sp.symbols("m2 m3 m4", real=True)
    m2, m3, m4 = theta
    _, _, z, phi, th, psi, e1, e2 = q

    def rx(a):
        return sp.Matrix([[1, 0, 0], [0, sp.cos(a), -sp.sin(a)], [0, sp.sin(a), sp.cos(a)]])

    def ry(a):
        return sp.Matrix([[sp.cos(a), 0, sp.sin(a)], [0, 1, 0], [-sp.sin(a), 0, sp.cos(a)]])

    def rz(a):
        return sp.Matrix([[sp.cos(a), -sp.sin(a), 0], [sp.sin(a), sp.cos(a), 0], [0, 0, 1]])

    def ddt(expr):
        return sum(sp.diff(expr, qi) * qdi for qi, qdi in zip(q, qd, strict=True))

    rot = rz(psi) * ry(th) * rx(phi)
    omega_skew = (rot.T * rot.applyfunc(ddt)).applyfunc(sp.simplify)
    omega = sp.Matrix([omega_skew[2, 1], omega_skew[0, 2], omega_skew[1, 0]])
    assert (omega_skew + omega_skew.T).applyfunc(sp.simplify) == sp.zeros(3, 3)

    p_dot_body = rot.T * sp.Matrix(qd[0:3])
    r_a = sp.Matrix([rax, ray, raz])
    u1 = sp.Matrix([sp.cos(e1), 0, sp.sin(e1)])
    u2 = sp.Matrix([sp.cos(e1 + e2), 0, sp.sin(e1 + e2)])

    def line_body_energy(origin, axis, mass, first, second):
        """Kinetic energy of a mass distribution on the line origin + s axis (body frame)."""
        a = p_dot_body + omega.cross(origin) + origin.applyfunc(ddt)
        b = omega.cross(axis) + axis.applyfunc(ddt)
        return sp.Rational(1, 2) * (mass * a.dot(a) + 2 * first * a.dot(b) + second * b.dot(b))

    inertia = sp.diag(ixx, iyy, izz)
    kinetic = (
        sp.Rational(1, 2) * mb * sp.Matrix(qd[0:3]).dot(sp.Matrix(qd[0:3]))
        + sp.Rational(1, 2) * (omega.T * inertia * omega)[0, 0]
        + line_body_energy(r_a, u1, m1, s1, j1)
        + line_body_energy(r_a + l1 * u1, u2, m2, m3, m4)
        + sp.Rational(1, 2) * (a1 * qd[6] ** 2 + a2 * qd[7] ** 2)
    )

    def height(origin, axis, mass, first):
        """Integral of the world z coordinate over the line mass (mass-weighted height)."""
        e3 = sp.Matrix([0, 0, 1])
        return mass * (z + e3.dot(rot * origin)) + first * e3.dot(rot * axis)

    potential = g * (mb * z + height(r_a, u1, m1, s1) + height(r_a + l1 * u1, u2, m2, m3))

    n = len(q)
    mass = sp.Matrix(n, n, lambda i, j: sp.expand(sp.diff(kinetic, qd[i], qd[j])))
    dmass = [mass.diff(qk) for qk in q]
    coriolis = sp.zeros(n, n)
    for k in range(n):
        for j in range(n):
            coriolis[k, j] = sp.expand(
                sum(
                    sp.Rational(1, 2) * (dmass[i][k, j] + dmass[j][k, i] - dmass[k][i, j]) * qd[i]
                    for i in range(n)
                )
            )
    gravity = sp.Matrix([sp.expand(sp.diff(potential, qk)) for qk in q])
    return q, qd, params, theta, mass, coriolis, gravity, sp.expand(potential)


def split(expr, theta):
    """Coefficients (known, m2, m3, m4) of an expression linear in theta."""
    import sympy as sp

    zero = dict.fromkeys(theta, 0)
    known = expr.subs(zero)
    parts = [known] + [sp.diff(expr, t) for t in theta]
    assert sp.expand(expr - known - sum(t * c for t, c in zip(theta, parts[1:], strict=True))) == 0
    return parts


_C_TEMPLATE = """\
/* Generated by companion.model.derive from the symbolic derivation; do not edit.
 * Regenerate with `python -m companion.model.derive`.
 *
 * mcg(q, qd, p, out): fills out (float64[4][136]) with the pieces of M, C and G that are the
 * coefficients of xi = [m2, m3, m4, 1]. Piece k holds 8 rows [M_k[i, 0:8] | C_k[i, 0:8] |
 * G_k[i]] (see companion/model/layout.py).
 * potential(q, p, out): fills out (float64[4]) with the potential energy pieces.
 * combine(pieces, xi, out) and regress(pieces, qr_dot, qr_ddot, out) are the two products
 * the controller needs on those pieces, all(q, qd, p, theta, qr_dot, qr_ddot, out) both of
 * them after mcg in one call (hand-written, not generated).
 * q, qd: float64[8]; p: float64[{n_params}] = {param_names}.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <string.h>

static void mcg_eval(const double *q, const double *qd, const double *p, double *out)
{{
{mcg_body}
}}

static void potential_eval(const double *q, const double *p, double *out)
{{
{potential_body}
}}

/* One argument: its name, its number of float64 values, whether it is written and whether
 * it must be one-dimensional. */
typedef struct {{ const char *name; Py_ssize_t n; int writable; int vector; }} Arg;

/* The buffers of args[0:count] as spec says, each C-contiguous native float64 ("d"),
 * or 0 with an error set (TypeError: the count of arguments or no buffer; ValueError:
 * another element type, byte order, shape or number of values) and none held. */
static int take(const char *function, PyObject *const *args, Py_ssize_t nargs,
                const Arg *spec, Py_ssize_t count, Py_buffer *b)
{{
    if (nargs != count) {{
        PyErr_Format(PyExc_TypeError, "%s() takes %zd arguments (%zd given)", function, count,
                     nargs);
        return 0;
    }}
    for (Py_ssize_t i = 0; i < count; ++i) {{
        int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (spec[i].writable ? PyBUF_WRITABLE : 0);
        int ok = PyObject_GetBuffer(args[i], &b[i], flags) == 0;
        if (ok && (b[i].format == NULL || strcmp(b[i].format, "d") != 0
                   || (spec[i].vector && b[i].ndim != 1)
                   || b[i].len != spec[i].n * (Py_ssize_t)sizeof(double))) {{
            PyErr_Format(PyExc_ValueError,
                         "%s: expected %zd native float64 values%s, got %zd bytes of format %s "
                         "in %d dimensions", spec[i].name, spec[i].n,
                         spec[i].vector ? " in one dimension" : "", b[i].len,
                         b[i].format == NULL ? "B" : b[i].format, b[i].ndim);
            PyBuffer_Release(&b[i]);
            ok = 0;
        }}
        if (!ok) {{
            while (i-- > 0) PyBuffer_Release(&b[i]);
            return 0;
        }}
    }}
    return 1;
}}

static PyObject *release(Py_buffer *b, Py_ssize_t count)
{{
    for (Py_ssize_t i = 0; i < count; ++i) PyBuffer_Release(&b[i]);
    Py_RETURN_NONE;
}}

#define D(b) ((const double *)(b).buf)

static PyObject *py_mcg(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{{
    static const Arg spec[] = {{
        {{"q", 8, 0, 1}}, {{"qd", 8, 0, 1}}, {{"p", {n_params}, 0, 1}}, {{"out", {mcg_size}, 1, 0}},
    }};
    Py_buffer b[4];
    if (!take("mcg", args, nargs, spec, 4, b)) return NULL;
    mcg_eval(D(b[0]), D(b[1]), D(b[2]), (double *)b[3].buf);
    return release(b, 4);
}}

static PyObject *py_potential(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{{
    static const Arg spec[] = {{{{"q", 8, 0, 1}}, {{"p", {n_params}, 0, 1}}, {{"out", 4, 1, 0}}}};
    Py_buffer b[3];
    if (!take("potential", args, nargs, spec, 3, b)) return NULL;
    potential_eval(D(b[0]), D(b[1]), (double *)b[2].buf);
    return release(b, 3);
}}

/* combine(pieces, xi, out): out[j] = sum_k xi[k] pieces[k][j]  (M, C, G rows for one theta) */
static PyObject *py_combine(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{{
    static const Arg spec[] = {{
        {{"pieces", 4 * {piece_size}, 0, 0}}, {{"xi", 4, 0, 1}}, {{"out", {piece_size}, 1, 0}},
    }};
    Py_buffer b[3];
    if (!take("combine", args, nargs, spec, 3, b)) return NULL;
    const double *p = D(b[0]), *w = D(b[1]);
    double *o = (double *)b[2].buf;
    for (int j = 0; j < {piece_size}; ++j)
        o[j] = w[0] * p[j] + w[1] * p[{piece_size} + j] + w[2] * p[2 * {piece_size} + j]
               + w[3] * p[3 * {piece_size} + j];
    return release(b, 3);
}}

/* regress(pieces, qr_dot, qr_ddot, out): out[k][i] = M_k[i] qr_ddot + C_k[i] qr_dot + G_k[i],
 * that is Y^T (4 x 8) */
static PyObject *py_regress(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{{
    static const Arg spec[] = {{
        {{"pieces", 4 * {piece_size}, 0, 0}}, {{"qr_dot", 8, 0, 1}}, {{"qr_ddot", 8, 0, 1}},
        {{"out", 32, 1, 0}},
    }};
    Py_buffer b[4];
    if (!take("regress", args, nargs, spec, 4, b)) return NULL;
    const double *p = D(b[0]), *v = D(b[1]), *a = D(b[2]);
    double *o = (double *)b[3].buf;
    for (int r = 0; r < 32; ++r, p += 17) {{
        double acc = p[16];
        for (int j = 0; j < 8; ++j) acc += p[j] * a[j] + p[8 + j] * v[j];
        o[r] = acc;
    }}
    return release(b, 4);
}}

/* all(q, qd, p, theta, qr_dot, qr_ddot, out): M (8 x 8), C (8 x 8), G (8) for
 * theta = (m2, m3, m4) and Y^T (4 x 8) in one call, 168 values */
static PyObject *py_all(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{{
    static const Arg spec[] = {{
        {{"q", 8, 0, 1}}, {{"qd", 8, 0, 1}}, {{"p", {n_params}, 0, 1}}, {{"theta", 3, 0, 1}},
        {{"qr_dot", 8, 0, 1}}, {{"qr_ddot", 8, 0, 1}}, {{"out", 168, 1, 0}},
    }};
    Py_buffer b[7];
    if (!take("all", args, nargs, spec, 7, b)) return NULL;
    double pieces[4 * {piece_size}];
    const double *t = D(b[3]), w[4] = {{t[0], t[1], t[2], 1.0}};
    const double *v = D(b[4]), *a = D(b[5]);
    double *o = (double *)b[6].buf;
    mcg_eval(D(b[0]), D(b[1]), D(b[2]), pieces);
    for (int i = 0; i < 8; ++i)
        for (int j = 0; j < 17; ++j) {{
            int at = 17 * i + j;
            double value = w[0] * pieces[at] + w[1] * pieces[{piece_size} + at]
                           + w[2] * pieces[2 * {piece_size} + at]
                           + w[3] * pieces[3 * {piece_size} + at];
            if (j < 8) o[8 * i + j] = value;
            else if (j < 16) o[64 + 8 * i + j - 8] = value;
            else o[128 + i] = value;
        }}
    const double *r = pieces;
    for (int k = 0; k < 32; ++k, r += 17) {{
        double acc = r[16];
        for (int j = 0; j < 8; ++j) acc += r[j] * a[j] + r[8 + j] * v[j];
        o[136 + k] = acc;
    }}
    return release(b, 7);
}}

#define FAST(f) (PyCFunction)(void (*)(void))(f), METH_FASTCALL

static PyMethodDef methods[] = {{
    {{"mcg", FAST(py_mcg), "mcg(q, qd, p, out): stacked M, C, G pieces into out."}},
    {{"potential", FAST(py_potential), "potential(q, p, out): V pieces into out."}},
    {{"combine", FAST(py_combine), "combine(pieces, xi, out): xi @ pieces into out."}},
    {{"regress", FAST(py_regress),
      "regress(pieces, qr_dot, qr_ddot, out): Y^T (4 x 8) into out."}},
    {{"all", FAST(py_all),
      "all(q, qd, p, theta, qr_dot, qr_ddot, out): M, C, G for theta and Y^T into out."}},
    {{NULL, NULL, 0, NULL}}
}};

static struct PyModuleDef module = {{
    PyModuleDef_HEAD_INIT, "_mcg", "Generated dynamics of the hexacopter + 2-DOF arm.", -1,
    methods
}};

/* The module, with mcg_eval's address in the capsule "mcg_eval" (its C type: mcg_eval.pxd),
 * which compiled callers (the control step's twin) call without the Python API. */
PyMODINIT_FUNC PyInit__mcg(void)
{{
    PyObject *m = PyModule_Create(&module);
    if (m == NULL) return NULL;
    PyObject *eval = PyCapsule_New((void *)mcg_eval, "{capsule}", NULL);
    int added = eval != NULL && PyModule_AddObjectRef(m, "mcg_eval", eval) == 0;
    Py_XDECREF(eval);
    if (!added) {{
        Py_DECREF(m);
        return NULL;
    }}
    return m;
}}
"""

_PXD_TEMPLATE = """\
# Generated by companion.model.derive; do not edit.
# The C type of mcg_eval, whose address companion.model._mcg exports as the capsule
# "{capsule}".
# mcg_eval(q, qd, p, out) fills out (float64[{mcg_size}]) as _mcg.mcg does, without
# checking its arguments (q, qd: float64[8]; p: float64[{n_params}]).

ctypedef void (*McgEval)(
    const double *q, const double *qd, const double *p, double *out
) noexcept nogil
"""


def _c_body(inputs, outputs):
    """C statements computing ``outputs`` into ``out[i]`` (zeros included) with CSE."""
    import sympy as sp
    from sympy.printing.c import C99CodePrinter

    printer = C99CodePrinter()
    lines = []
    for array, symbols in inputs:
        lines += [f"    const double {s} = {array}[{i}];" for i, s in enumerate(symbols)]
    nonzero = [i for i, e in enumerate(outputs) if e != 0]
    temps, reduced = sp.cse([outputs[i] for i in nonzero], optimizations="basic")
    lines += [f"    const double {t} = {printer.doprint(e)};" for t, e in temps]
    lines.append(f"    memset(out, 0, {len(outputs)} * sizeof(double));")
    lines += [
        f"    out[{i}] = {printer.doprint(e)};" for i, e in zip(nonzero, reduced, strict=True)
    ]
    return "\n".join(lines)


def generate() -> dict[Path, str]:
    """The full texts of ``_mcg.c`` and ``mcg_eval.pxd``, by path."""
    q, qd, params, theta, mass, coriolis, gravity, potential = derive()
    n = len(q)
    mass_parts = [[split(mass[i, j], theta) for j in range(n)] for i in range(n)]
    coriolis_parts = [[split(coriolis[i, j], theta) for j in range(n)] for i in range(n)]
    gravity_parts = [split(gravity[i], theta) for i in range(n)]
    flat = []
    for k in XI_ORDER:
        for i in range(n):
            flat += [mass_parts[i][j][k] for j in range(n)]
            flat += [coriolis_parts[i][j][k] for j in range(n)]
            flat.append(gravity_parts[i][k])
    sizes = {"mcg_size": len(flat), "n_params": len(params), "capsule": CAPSULE}
    source = _C_TEMPLATE.format(
        **sizes,
        piece_size=len(flat) // 4,
        param_names=", ".join(PARAM_NAMES),
        mcg_body=_c_body([("q", q), ("qd", qd), ("p", params)], flat),
        potential_body=_c_body(
            [("q", q), ("p", params)], [split(potential, theta)[k] for k in XI_ORDER]
        ),
    )
    return {TARGET: source, PXD_TARGET: _PXD_TEMPLATE.format(**sizes)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="fail if a file is stale")
    args = parser.parse_args(argv)
    texts = generate()
    if args.check:
        stale = [
            path for path, text in texts.items() if not path.exists() or path.read_text() != text
        ]
        for path in stale:
            print(f"{path} is stale: run python -m companion.model.derive", file=sys.stderr)
        if stale:
            return 1
        print(f"{', '.join(str(path) for path in texts)} are up to date")
        return 0
    for path, text in texts.items():
        path.write_text(text)
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
