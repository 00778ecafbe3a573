"""The explicit description of a vehicle model: what abyssal generates C from.

A model is a plain function returning a :class:`Model`: named states, inputs, runtime
parameters (with units and defaults), process-noise inputs, the dynamics and a measurement
``y = h(x, p)``, all as CasADi SX expressions. The dynamics come in one of two kinds:

* continuous: ``xdot = f(x, u, p, w)``, discretised by abyssal (``discretisation="rk4"`` or
  ``"euler"``, ``substeps`` per step), with the step length dt a runtime input;
* discrete: ``x_next = f_d(x, u, p, w, dt)`` given directly (``x_next=`` and the symbol ``dt=``
  it uses); ``discretisation`` is then ``"discrete"``.

Parameters are a runtime input of every generated function, so a user can change a
vehicle's mass or a leader vehicle's position without regenerating C; their defaults
are recorded in the manifest and used when the runtime is given ``p=None``
(``bundle.params(m=30.0)`` overrides them by name).

A model measures through :class:`Sensor`s: each its own h_k(x, p) with its outputs (names and units),
its own parameters (a DVL's lever arm, a leader vehicle's position), its declared noise, angle
outputs, nominal rate and latency. The model's stacked measurement is every sensor's outputs in
order, and each sensor's own parameters are appended to the model's parameter vector (named
``<sensor>_<parameter>``). A model given one ``y = h(x, p)`` instead has one sensor, named
``measurement``, with the model's outputs.

A model may declare its operating :class:`Envelope`: the nominal range of each state and input
(for Euler angles, where the kinematics are regular) and the step lengths it is meant for.
`abyssal verify` samples a model without a NumPy twin inside it; it is recorded in the manifest
and does not enter :meth:`Model.equations_hash` (it is not an equation).
"""
from __future__ import annotations

import hashlib
import keyword
import math
import re
from dataclasses import dataclass, field

import casadi as ca

C_IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
C_KEYWORDS = frozenset(
    "auto break case char const continue default do double else enum extern float for goto if inline int long "
    "register restrict return short signed sizeof static struct switch typedef union unsigned void volatile while "
    "_Bool _Complex _Imaginary".split()
)
KINDS = {"rk4": "continuous", "euler": "continuous", "discrete": "discrete"}


@dataclass(frozen=True)
class Quantity:
    """A named scalar of a model (a state, input, noise input or output)."""

    name: str
    unit: str
    description: str = ""


@dataclass(frozen=True)
class Parameter:
    """A runtime parameter with its default value."""

    name: str
    unit: str
    default: float
    description: str = ""


def c_identifier_problem(name) -> str | None:
    """Why `name` cannot name a generated C symbol, or None when it can."""
    if not isinstance(name, str) or not C_IDENTIFIER.match(name):
        return f"{name!r} is not a valid C identifier (letters, digits and _, not starting with a digit)"
    if name in C_KEYWORDS or keyword.iskeyword(name):
        return f"{name!r} is a reserved word"
    return None


#: The range of a state or input the envelope does not name (and of every one when a model declares
#: no envelope): a unit box about the rest state (zero), what an engineer would call "order one" in SI units.
DEFAULT_RANGE = (-1.0, 1.0)
#: The longest step `abyssal verify` tries when a model declares no max_dt: it derives the step from the model
#: (the largest dt up to this one at which the discretisation is stable at rest and across the box) and says so.
DEFAULT_MAX_DT = 0.5
DEFAULT_MIN_DT = 0.01


@dataclass(frozen=True)
class Envelope:
    """Where a model is meant to be used: nominal ranges of its states and inputs, and its step lengths.

    Fields
    ------
    states: state name -> (low, high), the nominal range of that state (low < high, both finite, in
        the state's unit). For an angle whose kinematics are singular somewhere (the pitch of Euler
        angles at +-pi/2), the range is where they are regular, e.g. ``"theta": (-1.4, 1.4)``.
    inputs: input name -> (low, high), likewise.
        A state or input not named gets ``DEFAULT_RANGE`` = [-1, 1].
    max_dt: the longest step [s] the model is meant for (> 0, finite), or None (the default): not declared,
        `abyssal verify` derives it from the model (the largest dt up to DEFAULT_MAX_DT at which the
        discretisation is stable across the box) and says so. A declared max_dt is a promise the filters
        keep: stepped with a longer dt, a filter warns once (``FilterBase``).
    min_dt: the shortest step [s] (0 < min_dt <= max_dt).

    ``abyssal verify`` draws a model's states, inputs and dt uniformly inside this box when the model
    has no NumPy twin. The names are checked against the Model it is given to
    (``Model(..., envelope=Envelope(...))``).
    """

    states: dict[str, tuple[float, float]] = field(default_factory=dict)
    inputs: dict[str, tuple[float, float]] = field(default_factory=dict)
    max_dt: float | None = None
    min_dt: float = DEFAULT_MIN_DT

    def __post_init__(self):
        for group in ("states", "inputs"):
            ranges = getattr(self, group)
            if not isinstance(ranges, dict):
                raise TypeError(f"Envelope {group} must be a dict name -> (low, high), got {type(ranges).__name__}")
            checked = {}
            for name, bounds in ranges.items():
                what = f"Envelope {group}[{name!r}]"
                try:
                    low, high = bounds
                    low, high = _real(low), _real(high)
                except (TypeError, ValueError):
                    raise ValueError(f"{what} must be a pair (low, high) of numbers, got {bounds!r}") from None
                if not (math.isfinite(low) and math.isfinite(high)):
                    raise ValueError(f"{what} = {bounds!r}: low and high must be finite")
                if not low < high:
                    raise ValueError(f"{what} = {bounds!r}: low must be < high")
                checked[name] = (low, high)
            object.__setattr__(self, group, checked)  # a copy: later edits of the caller's dict do not leak in
        for label in ("max_dt", "min_dt"):
            if label == "max_dt" and self.max_dt is None:
                continue
            try:
                value = _real(getattr(self, label))
            except (TypeError, ValueError):
                raise ValueError(f"Envelope {label} must be a number of seconds, got {getattr(self, label)!r}") from None
            if not math.isfinite(value) or value <= 0:
                raise ValueError(f"Envelope {label} = {value!r} s: must be positive and finite")
            object.__setattr__(self, label, value)
        if self.max_dt is not None and self.min_dt > self.max_dt:
            raise ValueError(f"Envelope min_dt = {self.min_dt!r} s is larger than max_dt = {self.max_dt!r} s")

    def __hash__(self):
        return hash((tuple(self.states.items()), tuple(self.inputs.items()), self.max_dt, self.min_dt))

    def resolved(self, state_names, input_names) -> tuple[dict, dict]:
        """(states, inputs): name -> (low, high) for every given name, DEFAULT_RANGE where not declared."""
        return ({n: self.states.get(n, DEFAULT_RANGE) for n in state_names},
                {n: self.inputs.get(n, DEFAULT_RANGE) for n in input_names})


def _real(value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) and not hasattr(value, "__float__"):
        raise TypeError(f"not a number: {value!r}")
    return float(value)


def envelope_record(envelope: Envelope | None, state_names, input_names) -> dict:
    """The manifest's "envelope" entry: every state's and input's range (defaults resolved), the dt range
    (max_dt None: not declared, derived by `abyssal verify`), whether the model declared an envelope (False:
    the defaults of a model that declares none) and the default range."""
    declared = envelope is not None
    envelope = envelope if declared else Envelope()
    states, inputs = envelope.resolved(state_names, input_names)
    return {"declared": declared, "states": {n: list(r) for n, r in states.items()},
            "inputs": {n: list(r) for n, r in inputs.items()}, "max_dt": envelope.max_dt, "min_dt": envelope.min_dt,
            "default_range": list(DEFAULT_RANGE)}


@dataclass(frozen=True, kw_only=True)
class Sensor:
    """One sensor of a model: y_k = h_k(x, p), with its own outputs, parameters, noise, angles and timing.

    Fields
    ------
    name: a C identifier, unique among the model's sensors; it prefixes its outputs and parameters in the
        model's stacked layout (``dvl_u``, ``dvl_lever_x``).
    outputs: one Quantity per output (name, unit, description).
    y: h_k as an SX column (n_y_k, 1) of the model's x, the model's own parameters p and this sensor's q.
    parameters: its own runtime parameters (Parameter: name, unit, default), e.g. a lever arm or the position
        of the vehicle it ranges to; a measurement may carry its own values (``update(sensor, z, t, p=...)``).
    q: the SX column of their symbols (one per parameter, in order; ``symbols("dvl", parameters)`` makes it).
    noise: its declared measurement noise: a standard deviation per output (in the output's unit) or an
        (n_y_k, n_y_k) covariance; None declares none (a filter is then given R).
    angle_outputs: indices (into its outputs) of angles: their innovations wrap to (-pi, pi].
    rate: its nominal rate in Hz (None: irregular); latency: seconds between a measurement's stamp and its
        arrival, a number or a (min, max) range (None: unknown). Both describe the sensor (manifest, exported
        header, simulators); a filter takes each measurement's own stamp.
    description: what it is.
    """

    name: str
    outputs: tuple[Quantity, ...]
    y: ca.SX
    parameters: tuple[Parameter, ...] = ()
    q: ca.SX | None = None
    noise: object = None
    angle_outputs: tuple[int, ...] = ()
    rate: float | None = None
    latency: float | tuple[float, float] | None = None
    description: str = ""

    def __post_init__(self):
        label = f"sensor {self.name!r}"
        problem = c_identifier_problem(self.name)
        if problem:
            raise ValueError(f"sensor name {problem}")
        object.__setattr__(self, "outputs", tuple(self.outputs))
        object.__setattr__(self, "parameters", tuple(self.parameters))
        object.__setattr__(self, "angle_outputs", tuple(self.angle_outputs))
        if not self.outputs:
            raise ValueError(f"{label}: it needs at least one output")
        if isinstance(self.y, ca.MX):
            raise ValueError(f"{label}: y is a casadi.MX expression; build it from casadi.SX")
        try:
            y = ca.SX(self.y)
        except (NotImplementedError, TypeError, RuntimeError) as exc:
            raise ValueError(f"{label}: y must be a casadi.SX expression, got {type(self.y).__name__} ({exc})") from None
        if y.shape != (len(self.outputs), 1):
            raise ValueError(f"{label}: y has shape {y.shape}, expected ({len(self.outputs)}, 1) (one row per output)")
        object.__setattr__(self, "y", y)
        q = ca.SX(0, 1) if self.q is None else ca.SX(self.q)
        if q.numel() != len(self.parameters) or (q.numel() and (q.size2() != 1 or not q.is_valid_input())):
            raise ValueError(f"{label}: q must be a column of {len(self.parameters)} plain SX symbols, one per parameter "
                             f"(symbols({self.name!r}, parameters) makes it), got shape {q.shape}")
        object.__setattr__(self, "q", q)
        for i in self.angle_outputs:
            if not isinstance(i, int) or isinstance(i, bool) or not 0 <= i < len(self.outputs):
                raise ValueError(f"{label}: angle_outputs index {i!r} is out of range 0..{len(self.outputs) - 1}")
        object.__setattr__(self, "noise", self._checked_noise())
        if self.rate is not None and not (isinstance(self.rate, (int, float)) and 0 < self.rate < math.inf):
            raise ValueError(f"{label}: rate must be a positive number of Hz or None, got {self.rate!r}")
        latency = self.latency
        if latency is not None:
            pair = (latency, latency) if isinstance(latency, (int, float)) else tuple(latency)
            if len(pair) != 2 or not all(isinstance(v, (int, float)) and 0 <= v < math.inf for v in pair) or pair[0] > pair[1]:
                raise ValueError(f"{label}: latency must be seconds >= 0 or a (min, max) range, got {latency!r}")
            object.__setattr__(self, "latency", (float(pair[0]), float(pair[1])))

    def _checked_noise(self):
        """The declared noise as a covariance (a tuple of row tuples), or None."""
        if self.noise is None:
            return None
        m, label = len(self.outputs), f"sensor {self.name!r}: noise"
        try:
            rows = [list(map(float, r)) for r in self.noise] if _is_matrix(self.noise) else [float(v) for v in self.noise]
        except (TypeError, ValueError):
            raise ValueError(f"{label} must be {m} standard deviations or an ({m}, {m}) covariance, got "
                             f"{self.noise!r}") from None
        if rows and isinstance(rows[0], float):
            if len(rows) != m or not all(0 < v < math.inf for v in rows):
                raise ValueError(f"{label}: {m} positive finite standard deviations expected, got {rows}")
            cov = [[rows[i] ** 2 if i == j else 0.0 for j in range(m)] for i in range(m)]
        else:
            cov = rows
            if len(cov) != m or any(len(r) != m for r in cov):
                raise ValueError(f"{label}: an ({m}, {m}) covariance expected")
            if not all(math.isfinite(v) for r in cov for v in r) or any(cov[i][j] != cov[j][i] for i in range(m)
                                                                        for j in range(m)):
                raise ValueError(f"{label}: the covariance must be finite and symmetric")
            if any(cov[i][i] <= 0 for i in range(m)) or not _positive_definite(cov):
                raise ValueError(f"{label}: the covariance must be positive definite")
        return tuple(tuple(r) for r in cov)

    @property
    def n_y(self) -> int:
        return len(self.outputs)

    @property
    def n_q(self) -> int:
        return len(self.parameters)


def _is_matrix(value) -> bool:
    try:
        first = next(iter(value))
    except (TypeError, StopIteration):
        return False
    return hasattr(first, "__iter__")


def _positive_definite(cov) -> bool:
    """Whether a small symmetric matrix is positive definite (a plain Cholesky)."""
    m = len(cov)
    L = [[0.0] * m for _ in range(m)]
    for j in range(m):
        d = cov[j][j] - sum(L[j][k] ** 2 for k in range(j))
        if not d > 0:
            return False
        L[j][j] = math.sqrt(d)
        for i in range(j + 1, m):
            L[i][j] = (cov[i][j] - sum(L[i][k] * L[j][k] for k in range(j))) / L[j][j]
    return True


#: the name of the one sensor of a model given by y = h(x, p)
DEFAULT_SENSOR = "measurement"


@dataclass(frozen=True, kw_only=True)
class Model:
    """Symbolic model of a vehicle.

    Fields
    ------
    name: identifier used for the generated folder and C symbol prefix (a C identifier).
    states, inputs, parameters, noises, outputs: descriptions, in vector order; names are C
        identifiers, unique within each group.
    x, u, p, w: the CasADi SX column symbols of those vectors (w may have 0 rows).
    xdot: continuous dynamics f(x, u, p, w), shape (n_x, 1); None for a discrete model.
    y: measurement h(x, p), shape (n_y, 1): one sensor, named "measurement", with the outputs above; or
    sensors: the model's sensors (:class:`Sensor`), instead of y and outputs. The model's outputs, y,
        angle_outputs and its parameters and p then include every sensor's (outputs ``<sensor>_<output>``
        stacked in the order of the sensors, parameters ``<sensor>_<parameter>`` appended).
    discretisation: "rk4" or "euler" for a continuous model (default "rk4"), "discrete" for a
        discrete one (the default when x_next is given); substeps: steps of dt/substeps in one call.
    angle_outputs: indices of outputs that are angles (innovations wrap to (-pi, pi]).
    angle_states: indices of states that are angles (the runtime wraps them; recorded in the manifest).
    notes: departures from the source paper, printed in the manifest.
    x_next: discrete dynamics f_d(x, u, p, w, dt), shape (n_x, 1), instead of xdot.
    dt: the SX scalar symbol of the step length used in x_next.
    functions: further CasADi SX Functions generated with the model into ``<name>_functions.c``
        (e.g. a noise law: tan3dof's fuzzy_sigma), each named ``<name>_<suffix>`` and loaded as
        ``bundle.function("<suffix>")``; ``abyssal verify`` compares their C with CasADi.
    envelope: the operating :class:`Envelope` (nominal state and input ranges, dt range); None
        declares none (verify then samples [-1, 1] about the rest state and dt up to the largest stable step
        it finds, at most 0.5 s, and says so). Recorded in the manifest; not part of equations_hash.

    Validation happens here, when the Model is built, so a mistake is reported next to the line
    that made it rather than as a compiler error or a silently wrong filter: SX (not MX)
    expressions, shapes, free symbols, C identifiers, duplicate names and index ranges.
    """

    name: str
    states: tuple[Quantity, ...]
    inputs: tuple[Quantity, ...]
    parameters: tuple[Parameter, ...] = ()
    noises: tuple[Quantity, ...] = ()
    outputs: tuple[Quantity, ...] = ()
    x: ca.SX
    u: ca.SX
    p: ca.SX | None = None
    w: ca.SX | None = None
    xdot: ca.SX | None = None
    y: ca.SX | None = None
    sensors: tuple[Sensor, ...] = ()
    discretisation: str | None = None
    substeps: int = 1
    angle_outputs: tuple[int, ...] = ()
    notes: tuple[str, ...] = field(default_factory=tuple)
    x_next: ca.SX | None = None
    dt: ca.SX | None = None
    angle_states: tuple[int, ...] = ()
    functions: tuple[ca.Function, ...] = ()
    envelope: Envelope | None = None

    def __post_init__(self):
        problem = c_identifier_problem(self.name)
        if problem:
            raise ValueError(f"model name {problem}: it names the generated folder and prefixes every C symbol")
        for label in ("p", "w"):
            if getattr(self, label) is None:
                object.__setattr__(self, label, ca.SX(0, 1))
        self._resolve_sensors()
        self._check_expressions()
        self._check_names()
        self._check_shapes()
        self._check_symbols()
        self._check_indices()
        self._check_functions()
        self._check_envelope()

    # ----------------------------------------------------------------- validation
    def _fail(self, message: str):
        raise ValueError(f"model {self.name!r}: {message}")

    def _resolve_sensors(self):
        """The stacked measurement from the sensors, or the one sensor of a model given by y and outputs."""
        sensors = tuple(self.sensors)
        if len(sensors) == 1 and isinstance(sensors[0], Sensor) and sensors[0].name == DEFAULT_SENSOR and self.y is not None:
            sensors = ()  # the one sensor of a model given by y (dataclasses.replace passes it back): rebuilt from y
        if sensors and self._resolved_form(sensors):  # a model rebuilt from a resolved one (dataclasses.replace)
            n_q = sum(s.n_q for s in sensors)
            object.__setattr__(self, "parameters", tuple(self.parameters)[: len(self.parameters) - n_q])
            object.__setattr__(self, "p", ca.SX(self.p)[: ca.SX(self.p).numel() - n_q])
            object.__setattr__(self, "outputs", ())
            object.__setattr__(self, "y", None)
            object.__setattr__(self, "angle_outputs", ())
        object.__setattr__(self, "_explicit_sensors", bool(sensors))
        if not sensors:
            if self.y is None:
                self._fail("it has no measurement: give y = h(x, p) with its outputs, or sensors=(Sensor(...), ...) "
                           "(abyssal.symbolic.Sensor); a filter needs at least one")
            outputs = tuple(self.outputs)
            try:
                y = ca.SX(self.y)
            except (NotImplementedError, TypeError, RuntimeError):
                y = self.y  # refused with its reason by _check_expressions
            angles_valid = all(isinstance(i, int) and not isinstance(i, bool) and 0 <= i < len(outputs)
                               for i in self.angle_outputs)  # else _check_indices names the problem
            if isinstance(y, ca.SX) and not isinstance(self.y, ca.MX) and y.shape == (len(outputs), 1) and outputs \
                    and angles_valid:
                sensor = Sensor(name=DEFAULT_SENSOR, outputs=outputs, y=y, angle_outputs=tuple(self.angle_outputs),
                                description="the model's measurement y = h(x, p)")
                object.__setattr__(self, "sensors", (sensor,))
            else:
                object.__setattr__(self, "sensors", ())
            return
        if self.y is not None or tuple(self.outputs) or tuple(self.angle_outputs):
            self._fail("give either y and outputs (one measurement) or sensors, not both; with sensors, the outputs, y "
                       "and angle_outputs are the sensors' stacked")
        names = [s.name for s in sensors if isinstance(s, Sensor)]
        if len(names) != len(sensors):
            self._fail("sensors must be abyssal Sensor objects (abyssal.symbolic.Sensor)")
        duplicates = sorted({n for n in names if names.count(n) > 1})
        if duplicates:
            self._fail(f"sensors: duplicate names {duplicates}")
        outputs, parameters, q, ys, angles, row = [], list(self.parameters), [ca.vec(ca.SX(self.p))], [], [], 0
        for s in sensors:
            outputs += [Quantity(f"{s.name}_{o.name}", o.unit, o.description) for o in s.outputs]
            parameters += [Parameter(f"{s.name}_{prm.name}", prm.unit, prm.default, prm.description) for prm in s.parameters]
            q.append(s.q)
            ys.append(s.y)
            angles += [row + i for i in s.angle_outputs]
            row += s.n_y
        object.__setattr__(self, "sensors", sensors)
        object.__setattr__(self, "outputs", tuple(outputs))
        object.__setattr__(self, "parameters", tuple(parameters))
        object.__setattr__(self, "p", ca.vertcat(*q))
        object.__setattr__(self, "y", ca.vertcat(*ys))
        object.__setattr__(self, "angle_outputs", tuple(angles))

    def _resolved_form(self, sensors) -> bool:
        """Whether outputs, y, parameters and p are already the stacked ones of these sensors (a resolved model passed
        back through dataclasses.replace), so that resolving again must not append the sensors' twice."""
        if self.y is None or not all(isinstance(s, Sensor) for s in sensors):
            return False
        names = [f"{s.name}_{o.name}" for s in sensors for o in s.outputs]
        own = [f"{s.name}_{q.name}" for s in sensors for q in s.parameters]
        parameters = [q.name for q in self.parameters]
        p = ca.SX(self.p)
        n_q = len(own)
        if [q.name for q in self.outputs] != names or parameters[len(parameters) - n_q:] != own or p.numel() < n_q:
            return False
        tail = [p[p.numel() - n_q + k] for k in range(n_q)]
        symbols_ = [s.q[k] for s in sensors for k in range(s.n_q)]
        return all(ca.is_equal(a, b) for a, b in zip(tail, symbols_))

    def _check_expressions(self):
        """Every expression is SX (MX refused, numbers converted); the kind is resolved."""
        discrete = self.x_next is not None
        if discrete and self.xdot is not None:
            self._fail("give either xdot (continuous) or x_next (discrete), not both")
        if not discrete and self.xdot is None:
            self._fail("give xdot (continuous dynamics) or x_next and dt (a discrete step)")
        if discrete and self.dt is None:
            self._fail("a discrete model needs dt=, the SX symbol of the step length x_next uses")
        if not discrete and self.dt is not None:
            self._fail("dt= is only for a discrete model (x_next); a continuous model gets dt from its discretisation")
        for label in ("x", "u", "p", "w", "xdot", "y", "x_next", "dt"):
            value = getattr(self, label)
            if value is None:
                continue
            if isinstance(value, ca.MX):
                self._fail(f"{label} is a casadi.MX expression; abyssal generates C from SX: build the model with "
                           "casadi.SX (ca.SX.sym, or abyssal.symbolic.model.symbols), not MX")
            if not isinstance(value, ca.SX):
                try:
                    value = ca.SX(value)
                except (NotImplementedError, TypeError, RuntimeError) as exc:
                    self._fail(f"{label} must be a casadi.SX expression, got {type(value).__name__} ({exc})")
                object.__setattr__(self, label, value)
        if self.discretisation is None:
            object.__setattr__(self, "discretisation", "discrete" if discrete else "rk4")
        if discrete and self.discretisation != "discrete":
            self._fail(f"a model given by x_next is discrete: discretisation must be 'discrete', got {self.discretisation!r}")
        if not discrete and self.discretisation not in ("rk4", "euler"):
            self._fail(f"discretisation must be 'rk4' or 'euler' for continuous dynamics, got {self.discretisation!r}")
        if not isinstance(self.substeps, int) or self.substeps < 1:
            self._fail(f"substeps must be an integer >= 1, got {self.substeps!r}")
        if discrete and self.substeps != 1:
            self._fail("substeps only applies to a discretised continuous model (x_next is one whole step)")

    def _check_names(self):
        groups = {"states": self.states, "inputs": self.inputs, "parameters": self.parameters,
                  "noises": self.noises, "outputs": self.outputs}
        for group, quantities in groups.items():
            seen = set()
            for q in quantities:
                problem = c_identifier_problem(q.name)
                if problem:
                    self._fail(f"{group}: name {problem}")
                if q.name in seen:
                    self._fail(f"{group}: duplicate name {q.name!r}")
                seen.add(q.name)
        for prm in self.parameters:
            if not isinstance(prm.default, (int, float)) or prm.default != prm.default or abs(prm.default) == float("inf"):
                self._fail(f"parameter {prm.name!r}: default must be a finite number, got {prm.default!r}")

    def _check_shapes(self):
        sizes = {
            "x/states": (self.x, self.states),
            "u/inputs": (self.u, self.inputs),
            "p/parameters": (self.p, self.parameters),
            "w/noises": (self.w, self.noises),
            "y/outputs": (self.y, self.outputs),
        }
        for label, (sym, described) in sizes.items():
            if sym.shape != (len(described), 1) and not (len(described) == 0 and sym.numel() == 0):
                self._fail(f"{label} has shape {sym.shape}, expected ({len(described)}, 1)")
        dynamics, label = (self.x_next, "x_next") if self.is_discrete else (self.xdot, "xdot")
        if dynamics.shape != self.x.shape:
            self._fail(f"{label} has shape {dynamics.shape}, expected {self.x.shape}")
        if self.is_discrete and self.dt.shape != (1, 1):
            self._fail(f"dt must be one SX symbol, got shape {self.dt.shape}")

    def _check_symbols(self):
        """x, u, p, w (and dt) are distinct plain symbols; the expressions use no other symbol."""
        declared = {"x": self.x, "u": self.u, "p": self.p, "w": self.w}
        if self.is_discrete:
            declared["dt"] = self.dt
        total = 0
        for label, sym in declared.items():
            if sym.numel() and not sym.is_valid_input():
                self._fail(f"{label} must be a vector of plain symbols (ca.SX.sym), not expressions")
            total += sym.numel()
        if len(ca.symvar(ca.vertcat(*[ca.vec(s) for s in declared.values()]))) != total:
            self._fail("x, u, p, w" + (", dt" if self.is_discrete else "") + " must not share symbols")

        def names(expr, allowed) -> list[str]:
            allowed_ids = {s.__hash__() for s in ca.symvar(ca.vertcat(*[ca.vec(a) for a in allowed]))}
            return sorted(s.name() for s in ca.symvar(expr) if s.__hash__() not in allowed_ids)

        if self.is_discrete:
            free = names(self.x_next, [self.x, self.u, self.p, self.w, self.dt])
            where = "x_next uses symbols {} that are not states, inputs, parameters, noises or dt"
        else:
            free = names(self.xdot, [self.x, self.u, self.p, self.w])
            where = "xdot uses symbols {} that are not states, inputs, parameters or noises (x, u, p, w)"
        if free:
            self._fail(where.format(free) + ": declare each as a Parameter (a runtime input) or substitute a number")
        free_h = names(self.y, [self.x, self.p])
        if free_h:
            self._fail(f"h may depend on x and p only, found {free_h} in y (an input in the measurement: make it a parameter)")
        if self._explicit_sensors:
            own = ca.vertcat(*[s.q for s in self.sensors])
            dynamics_p = self.p[: self.n_p - own.numel()]
            for s in self.sensors:
                free = names(s.y, [self.x, dynamics_p, s.q])
                if free:
                    self._fail(f"sensor {s.name!r}: its y uses {free}, which are not states, the model's parameters or "
                               "its own (another sensor's parameters, an input or a noise?)")
            if self.xdot is not None and ca.depends_on(self.xdot, own) or self.x_next is not None and ca.depends_on(self.x_next, own):
                self._fail("the dynamics use a sensor's own parameters; make them the model's parameters")

    def _check_functions(self):
        object.__setattr__(self, "functions", tuple(self.functions))
        for fn in self.functions:
            if not isinstance(fn, ca.Function):
                self._fail(f"functions: expected casadi.Function objects, got {type(fn).__name__}")
            label = f"functions: {fn.name()!r}"
            if not fn.name().startswith(self.name + "_") or c_identifier_problem(fn.name()):
                self._fail(f"{label} must be named {self.name}_<suffix> (a C identifier): it becomes a C symbol")
            if not fn.is_a("SXFunction"):
                self._fail(f"{label} is not an SX Function; abyssal generates C from SX (build it from casadi.SX)")
            if fn.has_free():
                self._fail(f"{label} has free symbols {fn.get_free()}: make them inputs")
        names = [fn.name() for fn in self.functions]
        duplicates = sorted({n for n in names if names.count(n) > 1})
        if duplicates:
            self._fail(f"functions: duplicate names {duplicates}")

    def _check_envelope(self):
        if self.envelope is None:
            return
        if not isinstance(self.envelope, Envelope):
            self._fail(f"envelope must be an abyssal Envelope (abyssal.symbolic.Envelope), got "
                       f"{type(self.envelope).__name__}")
        for group, quantities in (("states", self.states), ("inputs", self.inputs)):
            known = [q.name for q in quantities]
            unknown = [n for n in getattr(self.envelope, group) if n not in known]
            if unknown:
                self._fail(f"envelope {group}: {unknown} {'is not a' if len(unknown) == 1 else 'are not'} "
                           f"{group[:-1]} name{'s' if len(unknown) > 1 else ''} of the model; its {group}: {known}")

    def envelope_record(self) -> dict:
        """The manifest's "envelope" entry (see :func:`envelope_record`): ranges of every state and input."""
        return envelope_record(self.envelope, [q.name for q in self.states], [q.name for q in self.inputs])

    def _check_indices(self):
        for label, indices, n, what in (("angle_outputs", self.angle_outputs, self.n_y, "outputs"),
                                        ("angle_states", self.angle_states, self.n_x, "states")):
            indices = tuple(indices)
            object.__setattr__(self, label, indices)
            for i in indices:
                if not isinstance(i, int) or isinstance(i, bool) or not 0 <= i < n:
                    self._fail(f"{label} index {i!r} is out of range: the model has {n} {what} (0..{n - 1})")
            if len(set(indices)) != len(indices):
                self._fail(f"{label} {indices} repeats an index")

    # ----------------------------------------------------------------- sizes and names
    @property
    def is_discrete(self) -> bool:
        """True when the model gives its step x_next directly (no xdot, no discretisation)."""
        return self.x_next is not None

    @property
    def kind(self) -> str:
        return KINDS[self.discretisation]

    @property
    def n_x(self) -> int:
        return len(self.states)

    @property
    def n_u(self) -> int:
        return len(self.inputs)

    @property
    def n_p(self) -> int:
        return len(self.parameters)

    @property
    def n_w(self) -> int:
        return len(self.noises)

    @property
    def n_y(self) -> int:
        return len(self.outputs)

    @property
    def parameter_defaults(self) -> list[float]:
        return [prm.default for prm in self.parameters]

    @property
    def defaults(self) -> dict[str, float]:
        """Parameter name -> default value, in vector order."""
        return {prm.name: float(prm.default) for prm in self.parameters}

    def sensor_layout(self) -> list[dict]:
        """Per sensor: its name, its first output in the stacked measurement (offset), its first own parameter in p
        (p_offset, after the model's and earlier sensors' parameters) and sizes."""
        layout, row = [], 0
        p_offset = self.n_p - sum(s.n_q for s in self.sensors) if self._explicit_sensors else self.n_p
        for s in self.sensors:
            layout.append({"name": s.name, "offset": row, "n_y": s.n_y, "p_offset": p_offset, "n_q": s.n_q})
            row += s.n_y
            p_offset += s.n_q
        return layout

    def sensor(self, name: str) -> Sensor:
        """The sensor called name (KeyError listing the model's sensors)."""
        for s in self.sensors:
            if s.name == name:
                return s
        raise KeyError(f"model {self.name!r} has no sensor {name!r}; its sensors: {[s.name for s in self.sensors]}")

    def parameter_vector(self, **values: float) -> list[float]:
        """The parameter vector with the named entries changed: ``model.parameter_vector(m=30.0)``."""
        return parameter_vector(self.name, self.defaults, values)

    def parameter_table(self) -> str:
        """The parameters as a printable table: index, name, default, unit, description."""
        return parameter_table([(q.name, q.default, q.unit, q.description) for q in self.parameters])

    def equations_hash(self) -> str:
        """sha256 of the printed equations and discretisation: changes whenever the maths does."""
        names = " ".join(q.name for q in self.states + self.inputs + self.noises + self.outputs)
        defaults = " ".join(f"{q.name}={q.default!r}" for q in self.parameters)
        if self.is_discrete:
            dynamics = [f"dt={self.dt}", str(self.x_next)]
        else:
            dynamics = [str(self.xdot)]
        extra = [f"{fn.name()}: {fn.serialize()}" for fn in self.functions]
        sensors = [f"sensor {s.name}: {s.n_y} outputs, {s.n_q} parameters" for s in self.sensors] if self._explicit_sensors else []
        text = "\n".join([self.name, self.discretisation, str(self.substeps), str(self.angle_outputs), names, defaults,
                          *dynamics, str(self.y), *extra, *sensors])
        return hashlib.sha256(text.encode()).hexdigest()


def parameter_vector(model: str, defaults: dict[str, float], values: dict[str, float]) -> list[float]:
    """defaults with `values` replacing entries by name; an unknown name is an error listing the known ones."""
    unknown = sorted(set(values) - set(defaults))
    if unknown:
        raise KeyError(f"model {model!r} has no parameter(s) {unknown}; its parameters: {list(defaults)}")
    return [float(values.get(name, default)) for name, default in defaults.items()]


def parameter_table(rows) -> str:
    """Rows (name, default, unit, description) as an aligned text table."""
    cells = [("#", "name", "default", "unit", "description")]
    cells += [(str(i), n, f"{d:.6g}", u, desc) for i, (n, d, u, desc) in enumerate(rows)]
    widths = [max(len(r[k]) for r in cells) for k in range(5)]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in cells)


def symbols(prefix: str, quantities) -> ca.SX:
    """Column SX vector with one named symbol per quantity (``prefix`` keeps names unique)."""
    if len(quantities) == 0:
        return ca.SX(0, 1)
    return ca.vertcat(*[ca.SX.sym(f"{prefix}_{q.name}") for q in quantities])
