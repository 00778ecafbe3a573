/* abyssal_kalman_python.c: a Kalman filter's plain step(u, dt, z) and update(sensor, z, t) from Python in one C call,
 * as a CPython extension (module abyssal_kalman_python, built through abyssal's compile cache against the running
 * Python's headers). Not needed on a vehicle: `abyssal export` leaves this file out.
 *
 * One object per filter, installed as the filter's own `step` (an instance attribute over the class's method, so that
 * f.step(u, dt, z) is one C call with no Python frame), bound to the filter's C object, its call block, the runtime's
 * step and predict and the filter itself:
 *
 *     f.step = abyssal_kalman_python.StepCall(memory, block, code, step_address, predict_address, None,
 *                                             lock.locked, numpy.float64, f.__dict__, checked, refusal, warn_long_step)
 *
 * It takes the plain case only: positional (u, dt[, z[, None]]), u and z float64 vectors of their lengths (a buffer
 * of format 'd', contiguous), dt a float or NumPy float64, the model's own parameters (f._p_is_default), no unit watch
 * (f._unit_watch None) and the filter's lock free. Then it copies u and z into the call block as the checked path
 * does, calls the runtime's step (predict when z is None), writes its return code where the CasADi binding does
 * (`code`, the filter's f.code), says a step beyond f._max_dt once (warn_long_step), and
 * returns whether an update happened, or raises refusal(code, None, "step"). Anything else goes to checked(...)
 * with the arguments as given: the class's step (runtime/filters/kalman/engine.py), which holds every rule and every
 * message. The GIL is held throughout: no other Python thread runs during the call.
 *
 * UpdateCall is the same for a stamped sensor update, installed as the filter's own `update`:
 *
 *     f.update = abyssal_kalman_python.UpdateCall(memory, block, code, update_sensor_address, time_address, sensors,
 *                                                 lock.locked, numpy.float64, f.__dict__, checked, sensor_refusal,
 *                                                 warn_long_step)
 *
 * with sensors {name: index}: its plain case is update(name, z, t) with z a float64 vector of that sensor's outputs and
 * t a float; it writes z, t and the sensor into the call block, calls abyssal_kalman_update_sensor (no own R or
 * parameters), says once a prediction to t beyond f._max_dt, and returns whether a measurement entry was used, or
 * raises sensor_refusal(code, name, t, z).
 *
 * Hand-written C99; Python.h is included first, as its documentation asks.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <string.h>

#include "abyssal_kalman.h"

/* the call block's leading slots (abyssal_kalman_binding.c): [model, dt or t, sensor, has_R, has_q], then u, z, ... */
#define BLOCK_TIME 1
#define BLOCK_SENSOR 2
#define BLOCK_HEAD 5

typedef int (*step_function)(abyssal_kalman*, const abyssal_model*, const double*, double, const double*,
                             const unsigned char*, const double*);
typedef int (*predict_function)(abyssal_kalman*, const abyssal_model*, const double*, double, const double*);
typedef int (*update_sensor_function)(abyssal_kalman*, const abyssal_model*, int, double, const double*,
                                      const unsigned char*, const double*, const double*);
typedef double (*time_function)(const abyssal_kalman*);

typedef struct {
  PyObject_HEAD
  vectorcallfunc vectorcall;
  PyObject* filter_memory; /* the objects whose buffers the pointers below point into, held while this lives */
  PyObject* block_memory;
  PyObject* code_memory;
  PyObject* locked;        /* the filter lock's bound locked() */
  PyObject* float64;       /* numpy.float64, a dt the checked path takes as plain */
  PyObject* state;         /* the filter's __dict__: _p_is_default, _unit_watch, _max_dt */
  PyObject* checked;       /* the class's method (step or update) bound to the filter */
  PyObject* refusal;       /* the filter's _refusal or _sensor_refusal -> the exception to raise */
  PyObject* warn_long_step;/* the filter's _warn_long_step(dt, stacklevel) */
  PyObject* sensors;       /* UpdateCall: {name: index} */
  abyssal_kalman* filter;
  double* block;
  double* code;
  const abyssal_model* model;
  step_function step;
  predict_function predict;
  update_sensor_function update_sensor;
  time_function time;
  Py_ssize_t n_u, n_y;     /* the model's */
} OneCall; /* a StepCall's or an UpdateCall's object */

static PyObject *name_p_is_default, *name_unit_watch, *name_max_dt;

/* A contiguous float64 vector of n entries from `object`'s buffer into `to`; 0 when it is anything else (the error
 * a refusing buffer raises is cleared: the checked path judges that object again). */
static int copy_vector(PyObject* object, Py_ssize_t n, double* to) {
  Py_buffer view;
  int ok;
  if (!PyObject_CheckBuffer(object)) return 0;
  if (PyObject_GetBuffer(object, &view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) != 0) {
    PyErr_Clear();
    return 0;
  }
  ok = view.ndim == 1 && view.itemsize == (Py_ssize_t)sizeof(double) && view.len == n * (Py_ssize_t)sizeof(double) &&
       view.format != NULL && view.format[0] == 'd' && view.format[1] == '\0';
  if (ok) memcpy(to, view.buf, (size_t)view.len);
  PyBuffer_Release(&view);
  return ok;
}

/* The checked path with the arguments as given. */
static PyObject* checked(OneCall* self, PyObject* const* args, size_t nargsf, PyObject* kwnames) {
  return PyObject_Vectorcall(self->checked, args, nargsf, kwnames);
}

/* An accepted call's result: a step or a prediction of `elapsed` seconds beyond max_dt said once (the filter then
 * sets its _max_dt to inf; stacklevel 2: the user's line), and whether a measurement was used. */
static PyObject* accepted(OneCall* self, int code, double elapsed, PyObject* max_dt) {
  if (elapsed > PyFloat_AS_DOUBLE(max_dt)) {
    PyObject* said = PyObject_CallFunction(self->warn_long_step, "di", elapsed, 2);
    if (said == NULL) return NULL;
    Py_DECREF(said);
  }
  return PyBool_FromLong(code == 1);
}

/* A refused call: the exception the filter's refusal made (NULL: its own error) raised. */
static PyObject* refused(PyObject* error) {
  if (error == NULL) return NULL;
  PyErr_SetObject((PyObject*)Py_TYPE(error), error);
  Py_DECREF(error);
  return NULL;
}

/* The filter's own state allows the plain case: the model's parameters, no unit watch, a float max_dt (returned,
 * borrowed; NULL with no error set: take the checked path; NULL with an error: raise it) */
static PyObject* plain_state(OneCall* self) {
  PyObject *flag, *max_dt;
  flag = PyDict_GetItemWithError(self->state, name_p_is_default);
  if (flag != Py_True) return NULL;
  flag = PyDict_GetItemWithError(self->state, name_unit_watch);
  if (flag != Py_None) return NULL;
  max_dt = PyDict_GetItemWithError(self->state, name_max_dt);
  return max_dt != NULL && PyFloat_CheckExact(max_dt) ? max_dt : NULL;
}

/* 1 when the filter's lock is free, 0 when held, -1 with an error */
static int lock_free(OneCall* self) {
  PyObject* busy = PyObject_CallNoArgs(self->locked);
  int is_busy;
  if (busy == NULL) return -1;
  is_busy = PyObject_IsTrue(busy);
  Py_DECREF(busy);
  return is_busy < 0 ? -1 : !is_busy;
}

static PyObject* step_call(PyObject* self_object, PyObject* const* args, size_t nargsf, PyObject* kwnames) {
  OneCall* self = (OneCall*)self_object;
  const Py_ssize_t nargs = PyVectorcall_NARGS(nargsf);
  PyObject *z, *max_dt;
  double dt, *u_at, *z_at;
  int code, free_;
  if (kwnames != NULL || nargs < 2 || nargs > 4 || (nargs == 4 && args[3] != Py_None))
    return checked(self, args, nargsf, kwnames);
  z = nargs >= 3 ? args[2] : Py_None;
  if (PyFloat_CheckExact(args[1]) || (PyObject*)Py_TYPE(args[1]) == self->float64)
    dt = PyFloat_AS_DOUBLE(args[1]);
  else
    return checked(self, args, nargsf, kwnames);
  max_dt = plain_state(self);
  if (max_dt == NULL) return PyErr_Occurred() ? NULL : checked(self, args, nargsf, kwnames);
  free_ = lock_free(self);
  if (free_ <= 0) return free_ < 0 ? NULL : checked(self, args, nargsf, kwnames);
  /* u and z into the call block, as the checked path's memoryview assignments do (what one of them leaves there when
   * the other is refused, the checked path overwrites) */
  u_at = self->block + BLOCK_HEAD;
  z_at = u_at + self->n_u;
  if (!copy_vector(args[0], self->n_u, u_at) || (z != Py_None && !copy_vector(z, self->n_y, z_at)))
    return checked(self, args, nargsf, kwnames);
  self->block[BLOCK_TIME] = dt;
  code = z == Py_None ? self->predict(self->filter, self->model, u_at, dt, z_at + self->n_y)
                      : self->step(self->filter, self->model, u_at, dt, z_at, 0, z_at + self->n_y);
  self->code[0] = (double)code;
  return code >= 0 ? accepted(self, code, dt, max_dt)
                   : refused(PyObject_CallFunction(self->refusal, "dOs", (double)code, Py_None, "step"));
}

static PyObject* update_call(PyObject* self_object, PyObject* const* args, size_t nargsf, PyObject* kwnames) {
  OneCall* self = (OneCall*)self_object;
  const Py_ssize_t nargs = PyVectorcall_NARGS(nargsf);
  PyObject *index, *max_dt;
  double t, before, *z_at;
  long sensor;
  int code, free_;
  if (kwnames != NULL || nargs != 3 || !PyUnicode_CheckExact(args[0]))
    return checked(self, args, nargsf, kwnames);
  if (PyFloat_CheckExact(args[2]) || (PyObject*)Py_TYPE(args[2]) == self->float64)
    t = PyFloat_AS_DOUBLE(args[2]);
  else
    return checked(self, args, nargsf, kwnames);
  index = PyDict_GetItemWithError(self->sensors, args[0]);
  if (index == NULL) return PyErr_Occurred() ? NULL : checked(self, args, nargsf, kwnames);
  sensor = PyLong_AsLong(index);
  if (sensor < 0 || sensor >= self->model->n_sensors)
    return PyErr_Occurred() ? NULL : checked(self, args, nargsf, kwnames);
  max_dt = plain_state(self);
  if (max_dt == NULL) return PyErr_Occurred() ? NULL : checked(self, args, nargsf, kwnames);
  free_ = lock_free(self);
  if (free_ <= 0) return free_ < 0 ? NULL : checked(self, args, nargsf, kwnames);
  z_at = self->block + BLOCK_HEAD + self->n_u; /* the sensor's outputs take the first places of z */
  if (!copy_vector(args[1], self->model->sensors[sensor].n_y, z_at)) return checked(self, args, nargsf, kwnames);
  self->block[BLOCK_TIME] = t;
  self->block[BLOCK_SENSOR] = (double)sensor;
  before = self->time(self->filter);
  code = self->update_sensor(self->filter, self->model, (int)sensor, t, z_at, 0, 0, 0);
  self->code[0] = (double)code;
  return code >= 0 ? accepted(self, code, self->time(self->filter) - before, max_dt) /* (a late fix: 0 s ahead) */
                   : refused(PyObject_CallFunction(self->refusal, "iOOO", code, args[0], args[2], args[1]));
}

static int step_traverse(PyObject* self_object, visitproc visit, void* arg) {
  OneCall* self = (OneCall*)self_object;
  Py_VISIT(self->filter_memory);
  Py_VISIT(self->block_memory);
  Py_VISIT(self->code_memory);
  Py_VISIT(self->locked);
  Py_VISIT(self->float64);
  Py_VISIT(self->state);
  Py_VISIT(self->checked);
  Py_VISIT(self->refusal);
  Py_VISIT(self->warn_long_step);
  Py_VISIT(self->sensors);
  return 0;
}

static int step_clear(PyObject* self_object) {
  OneCall* self = (OneCall*)self_object;
  Py_CLEAR(self->filter_memory);
  Py_CLEAR(self->block_memory);
  Py_CLEAR(self->code_memory);
  Py_CLEAR(self->locked);
  Py_CLEAR(self->float64);
  Py_CLEAR(self->state);
  Py_CLEAR(self->checked);
  Py_CLEAR(self->refusal);
  Py_CLEAR(self->warn_long_step);
  Py_CLEAR(self->sensors);
  self->filter = NULL;
  self->block = NULL;
  self->code = NULL;
  return 0;
}

static void step_dealloc(PyObject* self_object) {
  PyObject_GC_UnTrack(self_object);
  step_clear(self_object);
  Py_TYPE(self_object)->tp_free(self_object);
}

/* The address of a writable buffer of at least `bytes` bytes held by `object` (a NumPy array), or NULL with an
 * error. */
static void* buffer_address(PyObject* object, Py_ssize_t bytes, const char* name) {
  Py_buffer view;
  void* address;
  if (PyObject_GetBuffer(object, &view, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS) != 0) return NULL;
  address = view.len >= bytes ? view.buf : NULL;
  PyBuffer_Release(&view);
  if (address == NULL) PyErr_Format(PyExc_ValueError, "abyssal_kalman_python: %s holds fewer than %zd bytes", name,
                                    bytes);
  return address;
}

static PyTypeObject StepCallType, UpdateCallType;

/* A function pointer from an address (ctypes' cast of the runtime library's symbol): converted through size_t, as
 * POSIX's dlsym requires of every platform this runs on. */
#define FUNCTION_AT(pointer, address) memcpy(&(pointer), &(size_t){(size_t)(address)}, sizeof(pointer))

/* Both types' constructor (the module docstring's arguments): the filter object, its call block (its model's
 * descriptor in the first 8 bytes; u and z of the model's sizes after the head), the return code's place, the
 * runtime's two functions, the sensors (UpdateCall; None for StepCall), the lock, the filter's state and callables. */
static PyObject* call_new(PyTypeObject* type, PyObject* args, PyObject* kwargs) {
  PyObject *filter_memory, *block_memory, *code_memory, *sensors, *locked, *float64, *state, *checked, *refusal,
      *warn_long_step;
  unsigned long long first_address, second_address, model_bits;
  const int update = type == &UpdateCallType;
  const abyssal_model* model;
  OneCall* self;
  double *block, *code;
  abyssal_kalman* filter;
  if (kwargs != NULL && PyDict_Size(kwargs) != 0) {
    PyErr_Format(PyExc_TypeError, "%s takes positional arguments only", type->tp_name);
    return NULL;
  }
  if (!PyArg_ParseTuple(args, "OOOKKOOOO!OOO", &filter_memory, &block_memory, &code_memory, &first_address,
                        &second_address, &sensors, &locked, &float64, &PyDict_Type, &state, &checked, &refusal,
                        &warn_long_step))
    return NULL;
  if (first_address == 0 || second_address == 0 || (update ? !PyDict_Check(sensors) : sensors != Py_None) ||
      !PyCallable_Check(locked) || !PyCallable_Check(checked) || !PyCallable_Check(refusal) ||
      !PyCallable_Check(warn_long_step)) {
    PyErr_Format(PyExc_TypeError, "%s: the runtime's two addresses, the sensors (a dict for UpdateCall, None for "
                 "StepCall), the lock's locked() and the filter's three callables", type->tp_name);
    return NULL;
  }
  filter = (abyssal_kalman*)buffer_address(filter_memory, 1, "the filter memory");
  if (filter == NULL) return NULL;
  block = (double*)buffer_address(block_memory, (Py_ssize_t)sizeof(double) * BLOCK_HEAD, "the call block");
  if (block == NULL) return NULL;
  memcpy(&model_bits, block, sizeof model_bits);
  if (model_bits == 0) {
    PyErr_Format(PyExc_ValueError, "%s: the call block names no model", type->tp_name);
    return NULL;
  }
  model = (const abyssal_model*)(size_t)model_bits;
  if (buffer_address(block_memory, (Py_ssize_t)sizeof(double) * (BLOCK_HEAD + model->n_u + model->n_y),
                     "the call block") == NULL)
    return NULL;
  code = (double*)buffer_address(code_memory, (Py_ssize_t)sizeof(double), "the return code");
  if (code == NULL) return NULL;
  self = (OneCall*)type->tp_alloc(type, 0);
  if (self == NULL) return NULL;
  self->vectorcall = update ? update_call : step_call;
  if (update) {
    FUNCTION_AT(self->update_sensor, first_address);
    FUNCTION_AT(self->time, second_address);
    Py_INCREF(sensors);
    self->sensors = sensors;
  } else {
    FUNCTION_AT(self->step, first_address);
    FUNCTION_AT(self->predict, second_address);
  }
  Py_INCREF(filter_memory);
  Py_INCREF(block_memory);
  Py_INCREF(code_memory);
  Py_INCREF(locked);
  Py_INCREF(float64);
  Py_INCREF(state);
  Py_INCREF(checked);
  Py_INCREF(refusal);
  Py_INCREF(warn_long_step);
  self->filter_memory = filter_memory;
  self->block_memory = block_memory;
  self->code_memory = code_memory;
  self->locked = locked;
  self->float64 = float64;
  self->state = state;
  self->checked = checked;
  self->refusal = refusal;
  self->warn_long_step = warn_long_step;
  self->filter = filter;
  self->block = block;
  self->code = code;
  self->model = model;
  self->n_u = model->n_u;
  self->n_y = model->n_y;
  return (PyObject*)self;
}

static PyObject* step_call_tuple(PyObject* self, PyObject* args, PyObject* kwargs) {
  return PyVectorcall_Call(self, args, kwargs);
}

/* The two types differ in name and doc only (call_new picks the vectorcall by the type). */
#define CALL_TYPE(name, doc)                                                                                   \
  {                                                                                                            \
    PyVarObject_HEAD_INIT(NULL, 0).tp_name = "abyssal_kalman_python." name, .tp_basicsize = sizeof(OneCall), \
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_GC | Py_TPFLAGS_HAVE_VECTORCALL, .tp_doc = doc,           \
    .tp_new = call_new, .tp_dealloc = step_dealloc, .tp_traverse = step_traverse, .tp_clear = step_clear,      \
    .tp_call = step_call_tuple, .tp_vectorcall_offset = offsetof(OneCall, vectorcall),                        \
  }

static PyTypeObject StepCallType = CALL_TYPE(
    "StepCall", "step(u, dt, z=None, p=None): predict(u, dt, p) then update(z, p) as one transaction; returns whether "
                "an update happened (a Kalman filter's step, its plain case in one C call)");
static PyTypeObject UpdateCallType = CALL_TYPE(
    "UpdateCall", "update(z, p=None) or update(sensor, z, t, R=None, p=None): a Kalman filter's update, its plain "
                  "stamped case update(sensor, z, t) in one C call");

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, .m_name = "abyssal_kalman_python", .m_size = -1,
    .m_doc = "A Kalman filter's plain step and stamped update from Python in one C call (abyssal_kalman_python.c).",
};

PyMODINIT_FUNC PyInit_abyssal_kalman_python(void) {
  PyObject* m;
  name_p_is_default = PyUnicode_InternFromString("_p_is_default");
  name_unit_watch = PyUnicode_InternFromString("_unit_watch");
  name_max_dt = PyUnicode_InternFromString("_max_dt");
  if (name_p_is_default == NULL || name_unit_watch == NULL || name_max_dt == NULL) return NULL;
  if (PyType_Ready(&StepCallType) < 0 || PyType_Ready(&UpdateCallType) < 0) return NULL;
  m = PyModule_Create(&module);
  if (m == NULL) return NULL;
  if (PyModule_AddObjectRef(m, "StepCall", (PyObject*)&StepCallType) < 0 ||
      PyModule_AddObjectRef(m, "UpdateCall", (PyObject*)&UpdateCallType) < 0) {
    Py_DECREF(m);
    return NULL;
  }
  return m;
}
