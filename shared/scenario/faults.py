"""Simulated faults for a world: the ``faults:`` section of a scenario and the named fault
profiles (``nominal``, ``lab``, ``harsh``, ``mismatch``), which ``--faults PROFILE|FILE`` names
too (read by :func:`server.options.load_faults`; ``hardware:`` and ``--hardware`` are their old
names, still accepted).

Only the world server reads it (:mod:`server.faults` applies it); the planner keeps the
nominal model and is never told, unless ``m3p2i run --compensate`` declares the delays to it as
``planner.delays`` (what a robot's owner would measure). Every fault is off by default. The
keys, their units and the profiles' numbers are documented in ``docs/faults.md``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

from shared.config import (
    ConfigError,
    Section,
    deprecated,
    flag,
    non_negative,
    one_of,
    positive,
)

GRIPPER_MODES = ("continuous", "binary")
# the scenario key's and the option's name before they were ``faults`` (read as ``faults``)
OLD_NAME = "hardware"


@dataclass(frozen=True)
class MismatchConfig:
    """Model mismatch: each factor is drawn per episode, from the seed, uniformly in
    ``[1 - f, 1 + f]`` (``f`` a fraction: 0.3 = ±30 %). ``mass``: per scenario object, its
    bodies' masses and inertias; ``friction``: per scenario object, its geoms' frictions;
    ``gain``: per actuator, its gain and bias (a position servo's kp and kv, a velocity servo's
    kv)."""

    mass: float = 0.0
    friction: float = 0.0
    gain: float = 0.0
    # exact factors instead of drawn ones: kind (mass, friction, gain) -> object or actuator ->
    # factor (a world whose box is 1.5 times as heavy: {mass: {box: 1.5}})
    factors: dict[str, dict[str, float]] = dataclasses.field(default_factory=dict)
    # what a friction factor scales: "geoms", each of the object's geoms' own friction (MuJoCo
    # takes the larger of two geoms', so a box's 0.5 under the floor's 1.0 decides nothing and
    # neither does its factor); "contacts", the friction of the object's contacts
    # (shared.scene.contact_friction)
    friction_of: str = "geoms"

    @property
    def active(self) -> bool:
        return bool(self.mass or self.friction or self.gain or self.factors)


@dataclass(frozen=True)
class FaultConfig:
    """The faults a simulated world shows (all off by default; docs/faults.md)."""

    actuation_delay_ms: float = 0.0  # a command reaches the actuators this much later
    state_delay_ms: float = 0.0  # a published state was measured this much earlier
    position_noise_m: float = 0.0  # Gaussian σ on a base's slides, free bodies' and mocap positions
    angle_noise_rad: float = 0.0  # Gaussian σ on free bodies' and mocap orientations
    joint_noise_rad: float = 0.0  # Gaussian σ on hinge joints (a robot arm's encoders)
    drop_rate: float = 0.0  # fraction of state messages the link loses
    hide_velocities: bool = False  # free objects' velocities published as zero
    control_period_ms: float = 0.0  # the actuators take a new command this often (0: every step)
    gripper: str = "continuous"  # binary: the gripper only opens or closes
    mismatch: MismatchConfig = MismatchConfig()
    scan_noise_m: float = 0.0  # Gaussian σ on the sensors' ranges (their returns)
    scan_dropout: float = 0.0  # fraction of the sensors' rays without a return
    scan_latency_ms: float = 0.0  # a sensor reading is delivered this much after it was measured

    @property
    def delays(self) -> tuple[float, float] | None:
        """``(actuation_delay_ms, state_delay_ms)`` for a planner to declare
        (``--compensate``), or None when neither is set."""
        if not (self.actuation_delay_ms or self.state_delay_ms):
            return None
        return self.actuation_delay_ms, self.state_delay_ms

    @property
    def active(self) -> bool:
        """Whether any fault is on (an inactive config leaves the world untouched)."""
        return self != FaultConfig()

    def to_dict(self) -> dict[str, Any]:
        """The config as plain values (the episode log's header)."""
        return dataclasses.asdict(self)


NOMINAL = FaultConfig()
PROFILES: dict[str, FaultConfig] = {
    # the simulation as it is: no fault
    "nominal": NOMINAL,
    # a well-kept lab: 50 ms round trip, a tracker with 5 mm noise over Wi-Fi losing one state
    # in ten, arm encoders good to 0.001 rad, object velocities not measured, a parallel gripper
    # that opens or closes, a model whose masses and frictions are right within ±30 %, and
    # sensors good to 1 cm that miss one ray in fifty and deliver their readings 50 ms late
    "lab": FaultConfig(
        actuation_delay_ms=25.0,
        state_delay_ms=25.0,
        position_noise_m=0.005,
        angle_noise_rad=0.005,
        joint_noise_rad=0.001,
        drop_rate=0.10,
        hide_velocities=True,
        control_period_ms=0.0,
        gripper="binary",
        mismatch=MismatchConfig(mass=0.3, friction=0.3, gain=0.1),
        scan_noise_m=0.01,
        scan_dropout=0.02,
        scan_latency_ms=50.0,
    ),
    # a bad day: 150 ms round trip, 15 mm noise, a third of the states lost, a 50 Hz actuator
    # loop, masses and frictions off by up to ±50 %, actuator gains by ±25 %, sensors good to
    # 3 cm that miss one ray in ten and deliver their readings 100 ms late
    "harsh": FaultConfig(
        actuation_delay_ms=75.0,
        state_delay_ms=75.0,
        position_noise_m=0.015,
        angle_noise_rad=0.015,
        joint_noise_rad=0.003,
        drop_rate=0.30,
        hide_velocities=True,
        control_period_ms=20.0,
        gripper="binary",
        mismatch=MismatchConfig(mass=0.5, friction=0.5, gain=0.25),
        scan_noise_m=0.03,
        scan_dropout=0.10,
        scan_latency_ms=100.0,
    ),
    # model error alone: harsh's masses, frictions (of the objects' contacts) and gains, and
    # nothing else (no delay, noise or loss)
    "mismatch": FaultConfig(
        mismatch=MismatchConfig(mass=0.5, friction=0.5, gain=0.25, friction_of="contacts"),
    ),
}


def _fraction(value: Any) -> float:
    v = non_negative(value)
    if v >= 1:
        raise ValueError("must be < 1")
    return v


def parse_faults(data: Any, source: str, path: str = "faults") -> FaultConfig:
    """A ``faults:`` value: a profile's name, or a mapping of keys (optionally ``profile:``,
    the base its other keys override). Raises :class:`ConfigError` naming file, key, value and
    what was expected."""
    if isinstance(data, str):
        return _profile(data, source, path)
    s = Section(data, source, path)
    base = NOMINAL
    if s.has("profile"):
        base = _profile(s.req("profile", str, "a profile name"), source, s.key_path("profile"))
    ms = "milliseconds >= 0"
    values = dict(
        actuation_delay_ms=s.opt("actuation_delay_ms", base.actuation_delay_ms, non_negative, ms),
        state_delay_ms=s.opt("state_delay_ms", base.state_delay_ms, non_negative, ms),
        position_noise_m=s.opt(
            "position_noise_m",
            base.position_noise_m,
            non_negative,
            "metres >= 0 (a standard deviation)",
        ),
        angle_noise_rad=s.opt(
            "angle_noise_rad",
            base.angle_noise_rad,
            non_negative,
            "radians >= 0 (a standard deviation)",
        ),
        joint_noise_rad=s.opt(
            "joint_noise_rad",
            base.joint_noise_rad,
            non_negative,
            "radians >= 0 (a standard deviation)",
        ),
        drop_rate=s.opt("drop_rate", base.drop_rate, _fraction, "a fraction in [0, 1)"),
        hide_velocities=s.opt("hide_velocities", base.hide_velocities, flag, "true or false"),
        control_period_ms=s.opt(
            "control_period_ms",
            base.control_period_ms,
            non_negative,
            "milliseconds >= 0 (0: every world step)",
        ),
        gripper=s.opt("gripper", base.gripper, one_of(GRIPPER_MODES), " or ".join(GRIPPER_MODES)),
        scan_noise_m=s.opt(
            "scan_noise_m", base.scan_noise_m, non_negative, "metres >= 0 (a standard deviation)"
        ),
        scan_dropout=s.opt("scan_dropout", base.scan_dropout, _fraction, "a fraction in [0, 1)"),
        scan_latency_ms=s.opt("scan_latency_ms", base.scan_latency_ms, non_negative, ms),
    )
    m = s.section("mismatch", required=False)
    frac = "a fraction in [0, 1) (0.3: factors within ±30 %)"
    values["mismatch"] = MismatchConfig(
        mass=m.opt("mass", base.mismatch.mass, _fraction, frac),
        friction=m.opt("friction", base.mismatch.friction, _fraction, frac),
        gain=m.opt("gain", base.mismatch.gain, _fraction, frac),
        factors=m.opt(
            "factors",
            base.mismatch.factors,
            _factors,
            "{mass|friction|gain: {object or actuator: factor > 0}}",
        ),
        friction_of=m.opt(
            "friction_of", base.mismatch.friction_of, one_of(FRICTION_OF), " or ".join(FRICTION_OF)
        ),
    )
    m.done()
    s.done()
    return FaultConfig(**values)


FRICTION_OF = ("geoms", "contacts")
MISMATCH_KINDS = ("mass", "friction", "gain")


def _factors(value: Any) -> dict[str, dict[str, float]]:
    if not isinstance(value, dict) or not all(k in MISMATCH_KINDS for k in value):
        raise ValueError(f"must map {', '.join(MISMATCH_KINDS)} to factors")
    out = {}
    for kind, named in value.items():
        if not isinstance(named, dict) or not all(isinstance(n, str) for n in named):
            raise ValueError(f"{kind}: must map names to factors")
        out[kind] = {n: positive(f) for n, f in named.items()}
    return out


def _profile(name: str, source: str, path: str) -> FaultConfig:
    if name not in PROFILES:
        raise ConfigError(
            source,
            path,
            "unknown fault profile",
            name,
            f"one of: {', '.join(PROFILES)} (or a mapping of keys)",
        )
    return PROFILES[name]


def read_old_name(raw: Any, source: str, path: str = "") -> Any:
    """The mapping ``raw`` (a scenario, a bench case, a faults file) with the old key
    ``hardware`` renamed ``faults``: the one place the old name is read. Both at once raise a
    :class:`ConfigError` naming ``source`` and both keys."""
    if not isinstance(raw, dict) or OLD_NAME not in raw:
        return raw
    if "faults" in raw:
        raise ConfigError(
            source,
            f"{path}.{OLD_NAME}" if path else OLD_NAME,
            "both faults: and hardware: (its old name) given",
            raw[OLD_NAME],
            "one of them: faults:",
        )
    deprecated(f"{OLD_NAME}: (in {source})", "write faults:")
    return {("faults" if k == OLD_NAME else k): v for k, v in raw.items()}


def steps_of(ms: float, dt: float) -> int:
    """Milliseconds as whole world steps of ``dt`` seconds, rounded up (lock-step delays,
    control period): what a real-time world of that period does too, where a command 25 ms
    late misses the tick it was sent for and is applied at the next."""
    return max(0, math.ceil(ms / 1000.0 / dt - 1e-9))
