"""Simulated co-workers: scripted pushes, random pushes (Drake's
``RandomSource``, seeded through the context), and a person reacting to the
robot's position."""

import dataclasses

import numpy as np
import numpy.typing as npt
from pydrake.systems.framework import LeafSystem

from drake_cfvol.exceptions import DimensionError, ParameterError
from drake_cfvol.systems._util import _vector

__all__ = ["Push", "RandomPushes", "Reactive", "ScriptedHuman", "ReactiveCoworker", "RandomPushShaper"]


@dataclasses.dataclass
class Push:
    """One push of the scripted human.

    Attributes:
        start: when it begins, s.
        duration: how long it lasts, s.
        joint_torque: joint torque (N m / N), length k, or empty.
        wrench: [torque (N m); force (N)] at the tool in the world frame, or empty.
        toward_nearest_obstacle: a force (N) at the tool, pointing from the
            robot to the obstacle nearest its moving links at the nominal
            when the push starts (the co-manipulation builder turns it into
            a wrench); 0: none.
    """

    start: float = 0.0
    duration: float = 1.0
    joint_torque: list[float] = dataclasses.field(default_factory=list)
    wrench: list[float] = dataclasses.field(default_factory=list)
    toward_nearest_obstacle: float = 0.0


@dataclasses.dataclass
class RandomPushes:
    """Random joint-torque pushes (count 0: none), drawn by Drake's
    ``RandomSource`` and seeded through the context: the run calls
    ``diagram.SetRandomContext(context, RandomGenerator(random_seed))``
    with the scenario's one ``random_seed``.

    Attributes:
        count: expected number of pushes over the run.
        max_torque: N m (N), per joint.
        mean_duration: s, the length of one push (the source's sampling
            interval).
    """

    count: int = 0
    max_torque: float = 300.0
    mean_duration: float = 1.0


@dataclasses.dataclass
class Reactive:
    """A co-worker who reacts to the robot's position (gain 0: none): see
    :class:`ReactiveCoworker`.

    Attributes:
        gain: N m/rad (N/m), per joint.
        offset: rad (m) per joint from the nominal: the pose the person wants
            (empty: zeros).
        start, duration: the window, s.
        max_torque: N m (N), per joint.
    """

    gain: float = 0.0
    offset: list[float] = dataclasses.field(default_factory=list)
    start: float = 0.0
    duration: float = 1e9
    max_torque: float = 400.0


class ScriptedHuman(LeafSystem):
    """A scripted co-worker: pushes as given, or seeded random ones.

    .. pydrake_system::

        name: ScriptedHuman
        output_ports:
        - human_torque
        - human_wrench

    Args:
        k: number of joints.
        pushes: the pushes (overlapping pushes add up).
    """

    def __init__(self, k: int, pushes: list[Push]):
        super().__init__()
        self.k = int(k)
        self.pushes = []
        for i, p in enumerate(pushes):
            if p.duration < 0:
                raise ParameterError(f"push {i}: duration must be >= 0 s, got {p.duration}.")
            tau = np.asarray(p.joint_torque, float) if len(p.joint_torque) else np.zeros(self.k)
            if p.toward_nearest_obstacle:
                raise ParameterError(
                    f"push {i}: toward_nearest_obstacle needs the workcell and the path; build "
                    "the diagram with drake_cfvol.comanip, which turns it into a wrench."
                )
            w = np.asarray(p.wrench, float) if len(p.wrench) else np.zeros(6)
            if tau.shape != (self.k,):
                raise DimensionError(f"push {i} joint_torque", self.k, tau.shape)
            if w.shape != (6,):
                raise DimensionError(f"push {i} wrench", 6, w.shape)
            self.pushes.append((float(p.start), float(p.start + p.duration), tau, w))
        self.human_torque_output = self.DeclareVectorOutputPort(
            name="human_torque",
            size=self.k,
            calc=lambda c, o: o.SetFromVector(self.at(c.get_time())[0]),
            prerequisites_of_calc={self.time_ticket()},
        )
        self.human_wrench_output = self.DeclareVectorOutputPort(
            name="human_wrench",
            size=6,
            calc=lambda c, o: o.SetFromVector(self.at(c.get_time())[1]),
            prerequisites_of_calc={self.time_ticket()},
        )

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        tau, w = np.zeros(self.k), np.zeros(6)
        for t0, t1, a, b in self.pushes:
            if t0 <= t < t1:
                tau += a
                w += b
        return tau, w


class ReactiveCoworker(LeafSystem):
    """A co-worker who reacts to where the robot is: a spring pulling it
    towards the nominal plus an offset (the pose the person wants), during
    a time window.

    .. pydrake_system::

        name: ReactiveCoworker
        input_ports:
        - commanded_position
        - nominal
        output_ports:
        - human_torque

    human_torque = clip(gain (nominal + offset - commanded_position),
    +-max_torque) for start <= t < start + duration, else 0. Fed from the
    admittance system's output it forms no algebraic loop (that output does
    not depend on the push).

    Args:
        k: number of joints.
        gain: N m/rad (N/m) per joint; scalar or (k,); >= 0.
        offset: rad (m) per joint; (k,).
        start, duration: the window, s.
        max_torque: N m (N) per joint; scalar or (k,); >= 0.
    """

    def __init__(
        self,
        k: int,
        *,
        gain: npt.ArrayLike,
        offset: npt.ArrayLike,
        start: float,
        duration: float,
        max_torque: npt.ArrayLike,
    ):
        super().__init__()
        self.k = int(k)
        self.gain = _vector(gain, k, "gain", nonnegative=True)
        self.offset = _vector(offset, k, "offset")
        self.max_torque = _vector(max_torque, k, "max_torque", nonnegative=True)
        if duration < 0:
            raise ParameterError(f"duration must be >= 0 s, got {duration}.")
        self.start, self.end = float(start), float(start + duration)
        self.commanded_position_input = self.DeclareVectorInputPort(name="commanded_position", size=self.k)
        self.nominal_input = self.DeclareVectorInputPort(name="nominal", size=self.k)
        self.human_torque_output = self.DeclareVectorOutputPort(name="human_torque", size=self.k, calc=self._calc)

    def _calc(self, context, output):
        t = context.get_time()
        if not self.start <= t < self.end:
            output.SetFromVector(np.zeros(self.k))
            return
        q = self.commanded_position_input.Eval(context)
        nominal = self.nominal_input.Eval(context)
        output.SetFromVector(np.clip(self.gain * (nominal + self.offset - q), -self.max_torque, self.max_torque))


class RandomPushShaper(LeafSystem):
    """Turns uniform random numbers into joint-torque pushes.

    .. pydrake_system::

        name: RandomPushShaper
        input_ports:
        - uniform
        output_ports:
        - human_torque

    Fed by Drake's ``RandomSource`` (uniform in [0, 1], held for one
    sampling interval): with u = [u_0, u_1 .. u_k], a push acts in that
    interval when u_0 < ``probability``, with joint torques
    (2 u_j - 1) x ``max_torque``; else the torque is zero. Randomness thus
    lives in the source's state, seeded through the context
    (``diagram.SetRandomContext(context, RandomGenerator(seed))``).

    Args:
        k: number of joints.
        probability: chance that an interval holds a push, in [0, 1].
        max_torque: N m (N) per joint; scalar or (k,); >= 0.
    """

    def __init__(self, k: int, *, probability: float, max_torque: npt.ArrayLike):
        super().__init__()
        if not 0.0 <= probability <= 1.0:
            raise ParameterError(f"probability must lie in [0, 1], got {probability}.")
        self.k = int(k)
        self.probability = float(probability)
        self.max_torque = _vector(max_torque, k, "max_torque", nonnegative=True)
        self.uniform_input = self.DeclareVectorInputPort(name="uniform", size=self.k + 1)
        self.human_torque_output = self.DeclareVectorOutputPort(
            name="human_torque", size=self.k, calc=lambda c, o: o.SetFromVector(self.torque(self.uniform_input.Eval(c)))
        )

    def torque(self, u: npt.ArrayLike) -> np.ndarray:
        """The push for random numbers u (k + 1,)."""
        u = np.asarray(u, float)
        if u[0] >= self.probability:
            return np.zeros(self.k)
        return (2.0 * u[1:] - 1.0) * self.max_torque
