"""The bounds table as a Drake system of the path index (SPEC 9)."""

import sys

import numpy as np
from pydrake.autodiffutils import AutoDiffXd
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem_, ValueProducer
from pydrake.systems.scalar_conversion import TemplateSystem

from drake_cfvol.algorithm.table import BoundsTable, check_table
from drake_cfvol.exceptions import ParameterError
from drake_cfvol.io.arguments import got
from drake_cfvol.systems._util import default_instantiation

__all__ = ["JointBoundsSource", "JointBoundsSource_"]


@TemplateSystem.define("JointBoundsSource_", T_list=(float, AutoDiffXd), scope=sys.modules[__name__])
def JointBoundsSource_(T):

    class Impl(LeafSystem_[T]):
        """Joint bounds for the current path index.

        .. pydrake_system::

            name: JointBoundsSource
            input_ports:
            - path_index
            - bounds (optional)
            output_ports:
            - lower
            - upper
            - nominal

        ``path_index`` is the path parameter s in [0, g-1] (a float; integer
        s is a waypoint). Between waypoints the bounds follow SPEC 7: the
        certified stretch box, changing at most at the table's rate per
        unit s and widened to hold the interpolated nominal.

        Scalar types: float and AutoDiffXd (``ToAutoDiffXd()``). With
        AutoDiffXd the outputs carry their derivative with respect to s:
        the nominal's exactly (linear between waypoints), the bounds' by a
        central difference of width 1e-7 (they are piecewise linear in s).
        Not Symbolic: the table is a lookup in s.

        ``bounds`` (optional, abstract): bounds that change during a run
        (an :class:`~drake_cfvol.systems.OnlineBoundsEstimator`'s
        ``bounds``, anything with the table's ``at(s)`` and ``g``); when
        connected they replace the table given here, which still fixes the
        number of joints.

        Args:
            bounds: the bounds table.
            clamp: clamp s into [0, g-1] instead of raising (default False:
                an s outside raises :class:`~drake_cfvol.ParameterError`).
        """

        def _construct(self, bounds: BoundsTable, *, clamp: bool = False, converter=None):
            LeafSystem_[T].__init__(self, converter)
            check_table(bounds, "JointBoundsSource: bounds")
            if not isinstance(clamp, bool):
                raise ParameterError(f"JointBoundsSource: clamp must be True or False, got {got(clamp)}.")
            self._bounds = bounds
            self._clamp = clamp
            k = bounds.k
            self.path_index_input = self.DeclareVectorInputPort(name="path_index", size=1)
            self.bounds_input = self.DeclareAbstractInputPort(name="bounds", model_value=AbstractValue.Make(bounds))
            tickets = {self.path_index_input.ticket(), self.bounds_input.ticket()}
            # The three outputs share one lookup per path index (a cache entry).
            self._box = self.DeclareCacheEntry(
                description="(lower, upper, nominal) at the path index",
                value_producer=ValueProducer(
                    allocate=lambda: AbstractValue.Make(object()),
                    calc=lambda ctx, value: value.set_value(self._at(ctx)),
                ),
                prerequisites_of_calc=tickets,
            )
            self.lower_output = self.DeclareVectorOutputPort(
                name="lower",
                size=k,
                calc=lambda ctx, out: out.SetFromVector(self._box.Eval(ctx)[0]),
                prerequisites_of_calc=tickets,
            )
            self.upper_output = self.DeclareVectorOutputPort(
                name="upper",
                size=k,
                calc=lambda ctx, out: out.SetFromVector(self._box.Eval(ctx)[1]),
                prerequisites_of_calc=tickets,
            )
            self.nominal_output = self.DeclareVectorOutputPort(
                name="nominal",
                size=k,
                calc=lambda ctx, out: out.SetFromVector(self._box.Eval(ctx)[2]),
                prerequisites_of_calc=tickets,
            )

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other._bounds, clamp=other._clamp, converter=converter)

        @property
        def bounds(self) -> BoundsTable:
            return self._bounds

        def _lookup(self, s: float, bounds=None):
            bounds = self._bounds if bounds is None else bounds
            if self._clamp:
                s = min(max(s, 0.0), bounds.g - 1.0) if np.isfinite(s) else s
            return bounds.at(s)

        def _at(self, context):
            s_in = self.path_index_input.Eval(context)[0]
            live = self.bounds_input.Eval(context) if self.bounds_input.HasValue(context) else None
            if T is float:
                return self._lookup(float(s_in), live)
            s = float(s_in.value())
            lo, hi, nom = self._lookup(s, live)
            ds = s_in.derivatives()
            g = self._bounds.g
            h = 1e-7
            a, b = max(s - h, 0.0), min(s + h, g - 1.0)
            if b > a:
                lo_a, hi_a, nom_a = self._lookup(a, live)
                lo_b, hi_b, nom_b = self._lookup(b, live)
                slopes = [(lo_b - lo_a) / (b - a), (hi_b - hi_a) / (b - a)]
                i = min(int(np.floor(s)), g - 2)
                slopes.append(self._bounds.nominal[i + 1] - self._bounds.nominal[i] if g > 1 else 0 * nom)
            else:
                slopes = [0 * lo, 0 * hi, 0 * nom]
            return tuple(
                np.array([AutoDiffXd(float(v), float(dv) * ds) for v, dv in zip(val, slope)], dtype=object)
                for val, slope in zip((lo, hi, nom), slopes)
            )

    return Impl


#: The float instantiation (``JointBoundsSource_[AutoDiffXd]`` by conversion).
JointBoundsSource = default_instantiation(JointBoundsSource_)
