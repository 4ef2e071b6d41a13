/* Compiled per-step physics of the simulated XM430 servo (sitl.servo.xm430).
 *
 * set_state(table, loop, constants, angle_rad, rate_rad_s) -> bool
 *     XM430Servo.set_state: the shaft's angle and rate into the loop state and into Present
 *     Velocity(128) and Present Position(132) of the control table.
 * step(table, loop, constants, dt_s) -> bool
 *     XM430Servo.step: the bus watchdog, the velocity profile, the position/current command,
 *     the supply's voltage limit, the current loop's lag, the overload timer and Present
 *     Current(126).
 *
 * The same operations in the same order as the Python methods (built without floating-point
 * contraction), which stay the reference (tests/test_xm430_model.py runs both and compares
 * the tables and loop states bit for bit). A call that would raise in Python (a value out
 * of its entry's range, a negative time step) or that sets the Overload bit changes nothing
 * and returns False: the caller then runs the Python method, which does it all. Table
 * offsets, unit sizes and mode numbers come from Python (``constants``), never from here.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>

/* loop state, float64 (XM430Servo._loop) */
enum { L_ANGLE, L_RATE, L_CURRENT, L_LAG_DT, L_LAG, L_OVERLOAD, L_SILENT, L_HOLD, L_PROFILE, N_LOOP };

/* constants, float64 (XM430Servo._constants) */
enum {
    C_TORQUE_CONSTANT, C_CURRENT_TIME_CONSTANT, C_KP, C_KD, C_OVERLOAD_FRACTION,
    C_OVERLOAD_TIME, C_RESISTANCE, C_BACK_EMF, C_FRICTION,
    C_RAD_PER_TICK, C_CENTER_TICKS, C_VELOCITY_UNIT, C_CURRENT_UNIT, C_VOLTAGE_UNIT,
    C_TORQUE_ENABLE, C_OPERATING_MODE, C_CURRENT_LIMIT, C_GOAL_CURRENT, C_GOAL_POSITION,
    C_PRESENT_CURRENT, C_PRESENT_VELOCITY, C_PRESENT_INPUT_VOLTAGE, C_PROFILE_VELOCITY,
    C_BUS_WATCHDOG, C_TRIPPED, C_WATCHDOG_MAX, C_WATCHDOG_UNIT_S, C_CURRENT_MODE,
    C_CURRENT_BASED_POSITION_MODE, C_TABLE_SIZE, N_CONSTANTS
};

typedef struct {
    Py_buffer table, loop, constants;
    int held;
} Views;

static void release(Views *v)
{
    if (v->held > 0) PyBuffer_Release(&v->table);
    if (v->held > 1) PyBuffer_Release(&v->loop);
    if (v->held > 2) PyBuffer_Release(&v->constants);
    v->held = 0;
}

static int acquire(PyObject *const *args, Views *v)
{
    v->held = 0;
    if (PyObject_GetBuffer(args[0], &v->table, PyBUF_C_CONTIGUOUS | PyBUF_WRITABLE) < 0)
        return 0;
    v->held = 1;
    if (PyObject_GetBuffer(args[1], &v->loop, PyBUF_C_CONTIGUOUS | PyBUF_WRITABLE | PyBUF_FORMAT)
        < 0)
        goto fail;
    v->held = 2;
    if (PyObject_GetBuffer(args[2], &v->constants, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
        goto fail;
    v->held = 3;
    if (v->loop.len != N_LOOP * (Py_ssize_t)sizeof(double) || v->loop.format == NULL
        || strcmp(v->loop.format, "d") != 0
        || v->constants.len != N_CONSTANTS * (Py_ssize_t)sizeof(double)
        || v->constants.format == NULL || strcmp(v->constants.format, "d") != 0) {
        PyErr_SetString(PyExc_ValueError, "loop or constants: wrong float64 buffer");
        goto fail;
    }
    if (v->table.len != (Py_ssize_t)((const double *)v->constants.buf)[C_TABLE_SIZE]) {
        PyErr_SetString(PyExc_ValueError, "table: wrong size");
        goto fail;
    }
    return 1;
fail:
    release(v);
    return 0;
}

static uint32_t get_u(const uint8_t *t, double offset, int size)
{
    size_t a = (size_t)offset;
    uint32_t value = 0;
    for (int i = size - 1; i >= 0; i--) value = (value << 8) | t[a + (size_t)i];
    return value;
}

static void put_u(uint8_t *t, double offset, int size, uint32_t value)
{
    size_t a = (size_t)offset;
    for (int i = 0; i < size; i++) t[a + (size_t)i] = (uint8_t)(value >> (8 * i));
}

/* Python's min(a, b) and max(a, b) for floats: the first argument unless the second is
 * strictly smaller (larger), NaN included. */
static double py_min(double a, double b) { return b < a ? b : a; }
static double py_max(double a, double b) { return b > a ? b : a; }

/* round(value / unit) as Python rounds it (half to even), if it lies in [low, high]. */
static int to_units(double value, double unit, double low, double high, int64_t *out)
{
    if (!isfinite(value)) return 0;
    double r = nearbyint(value / unit);
    if (!(r >= low && r <= high)) return 0;
    *out = (int64_t)r;
    return 1;
}

/* A call's (table, loop, constants) views and the n floats after them (nargs must be
 * 3 + n; ``usage`` is the TypeError's text). */
static int begin(PyObject *const *args, Py_ssize_t nargs, Py_ssize_t n, const char *usage,
                 double *values, Views *v)
{
    if (nargs != 3 + n) {
        PyErr_SetString(PyExc_TypeError, usage);
        return 0;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        values[i] = PyFloat_AsDouble(args[3 + i]);
        if (values[i] == -1.0 && PyErr_Occurred()) return 0;
    }
    return acquire(args, v);
}

static PyObject *py_set_state(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    double in[2];
    Views v;
    if (!begin(args, nargs, 2, "set_state(table, loop, constants, angle, rate)", in, &v))
        return NULL;
    double angle = in[0], rate = in[1];
    uint8_t *t = (uint8_t *)v.table.buf;
    double *s = (double *)v.loop.buf;
    const double *c = (const double *)v.constants.buf;
    int64_t ticks, velocity;
    int ok = to_units(angle, c[C_RAD_PER_TICK], -2147483648.0 - c[C_CENTER_TICKS],
                      2147483647.0 - c[C_CENTER_TICKS], &ticks)
             && to_units(rate, c[C_VELOCITY_UNIT], -2147483648.0, 2147483647.0, &velocity);
    if (ok) {
        s[L_ANGLE] = angle;
        s[L_RATE] = rate;
        ticks += (int64_t)c[C_CENTER_TICKS];
        put_u(t, c[C_PRESENT_VELOCITY], 4, (uint32_t)(int32_t)velocity);
        put_u(t, c[C_PRESENT_VELOCITY] + 4, 4, (uint32_t)(int32_t)ticks);
    }
    release(&v);
    return PyBool_FromLong(ok);
}

static PyObject *py_step(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    double dt;
    Views v;
    if (!begin(args, nargs, 1, "step(table, loop, constants, dt_s)", &dt, &v)) return NULL;
    uint8_t *t = (uint8_t *)v.table.buf;
    double *s = (double *)v.loop.buf;
    const double *c = (const double *)v.constants.buf;
    int ok = dt >= 0.0;
    if (!ok) goto done;

    double angle = s[L_ANGLE], rate = s[L_RATE], silent = s[L_SILENT], hold = s[L_HOLD];
    double profile = s[L_PROFILE];
    int torque_on = t[(size_t)c[C_TORQUE_ENABLE]] == 1;
    uint8_t watchdog = t[(size_t)c[C_BUS_WATCHDOG]];
    int tripping = 0;

    /* _watch */
    if (!torque_on || !(0 < watchdog && watchdog <= c[C_WATCHDOG_MAX])) {
        silent = 0.0;
    } else {
        silent += dt;
        if (silent > watchdog * c[C_WATCHDOG_UNIT_S]) {
            tripping = 1;
            watchdog = (uint8_t)c[C_TRIPPED];
            hold = angle;
        }
    }
    /* _advance_profile */
    int mode = t[(size_t)c[C_OPERATING_MODE]];
    uint32_t profile_units = get_u(t, c[C_PROFILE_VELOCITY], 4);
    double goal_position_rad =
        ((double)(int32_t)get_u(t, c[C_GOAL_POSITION], 4) - c[C_CENTER_TICKS]) * c[C_RAD_PER_TICK];
    if (!torque_on) {
        profile = angle;
    } else if (mode != (int)c[C_CURRENT_MODE]) {
        double profile_rate = profile_units * c[C_VELOCITY_UNIT];
        if (profile_rate == 0.0) {
            profile = goal_position_rad;
        } else {
            double step = profile_rate * dt;
            profile += py_max(-step, py_min(step, goal_position_rad - profile));
        }
    }
    /* _limit_a, _command_a */
    double limit = get_u(t, c[C_CURRENT_LIMIT], 2) * c[C_CURRENT_UNIT];
    double command = 0.0;
    if (torque_on) {
        double limit_a = limit;
        double goal_a = (double)(int16_t)get_u(t, c[C_GOAL_CURRENT], 2) * c[C_CURRENT_UNIT];
        int tripped = watchdog == (uint8_t)c[C_TRIPPED];
        if (mode == (int)c[C_CURRENT_MODE]) {
            command = tripped ? 0.0 : goal_a;
        } else {
            double goal_rad;
            if (tripped)
                goal_rad = hold;
            else if (profile_units == 0)
                goal_rad = goal_position_rad;
            else
                goal_rad = profile;
            command = c[C_KP] * (goal_rad - angle);
            command -= c[C_KD] * rate;
            if (mode == (int)c[C_CURRENT_BASED_POSITION_MODE]) limit_a = py_min(limit_a, fabs(goal_a));
        }
        command = py_max(-limit_a, py_min(limit_a, command));
    }
    /* _drivable_a */
    double volts = get_u(t, c[C_PRESENT_INPUT_VOLTAGE], 2) * c[C_VOLTAGE_UNIT];
    double emf = c[C_BACK_EMF] * rate;
    double low = (-volts - emf) / c[C_RESISTANCE];
    double high = (volts - emf) / c[C_RESISTANCE];
    double driven = py_max(low, py_min(high, command));
    /* the current loop */
    double lag_dt = s[L_LAG_DT], lag = s[L_LAG];
    if (dt != lag_dt) {
        lag_dt = dt;
        lag = -expm1(-dt / c[C_CURRENT_TIME_CONSTANT]);
    }
    double current = s[L_CURRENT] + (driven - s[L_CURRENT]) * lag;
    double threshold = c[C_OVERLOAD_FRACTION] * limit;
    int overloaded = fabs(command) >= threshold && threshold > 0.0;
    double overload = overloaded ? s[L_OVERLOAD] + dt : 0.0;
    if (overload >= c[C_OVERLOAD_TIME]) {
        ok = 0; /* the Overload bit and its shutdown: the Python step does all of it */
        goto done;
    }
    if (!torque_on) current = 0.0;
    int64_t units;
    if (!to_units(current, c[C_CURRENT_UNIT], -32768.0, 32767.0, &units)) {
        ok = 0;
        goto done;
    }
    s[L_SILENT] = silent;
    s[L_HOLD] = hold;
    s[L_PROFILE] = profile;
    s[L_LAG_DT] = lag_dt;
    s[L_LAG] = lag;
    s[L_CURRENT] = current;
    s[L_OVERLOAD] = overload;
    if (tripping) t[(size_t)c[C_BUS_WATCHDOG]] = watchdog;
    put_u(t, c[C_PRESENT_CURRENT], 2, (uint32_t)(uint16_t)(int16_t)units);
done:
    release(&v);
    return PyBool_FromLong(ok);
}

static PyMethodDef methods[] = {
    {"set_state", (PyCFunction)(void (*)(void))py_set_state, METH_FASTCALL,
     "set_state(table, loop, constants, angle_rad, rate_rad_s) -> bool: XM430Servo.set_state."},
    {"step", (PyCFunction)(void (*)(void))py_step, METH_FASTCALL,
     "step(table, loop, constants, dt_s) -> bool: XM430Servo.step (False: nothing done)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_xm430", "Compiled per-step physics of the simulated XM430 servo.",
    -1, methods,
};

PyMODINIT_FUNC PyInit__xm430(void) { return PyModule_Create(&module); }
