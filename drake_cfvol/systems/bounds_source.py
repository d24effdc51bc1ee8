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
            - lower_ahead
            - upper_ahead

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

        ``lower_ahead`` and ``upper_ahead`` are the box a robot braking in
        time keeps (the safety filter's faces under acceleration limits):
        with ``lookahead`` L > 0 (float only), about the nominal at s, each
        joint's deviation from the nominal no larger than the boxes allow
        anywhere in [s, s + L] (the boxes' deviations sampled at every
        waypoint and at quarter steps between): a face that will close in
        is seen while there is still time to brake for it. It lies inside
        the box at s and holds the nominal; with L = 0 it is the box at s.

        Args:
            bounds: the bounds table.
            clamp: clamp s into [0, g-1] instead of raising (default False:
                an s outside raises :class:`~drake_cfvol.ParameterError`).
            lookahead: L, path index units (>= 0; 0: the box at s).
        """

        def _construct(self, bounds: BoundsTable, *, clamp: bool = False, lookahead: float = 0.0, converter=None):
            LeafSystem_[T].__init__(self, converter)
            check_table(bounds, "JointBoundsSource: bounds")
            if not isinstance(clamp, bool):
                raise ParameterError(f"JointBoundsSource: clamp must be True or False, got {got(clamp)}.")
            if not 0.0 <= lookahead < np.inf:
                raise ParameterError(f"JointBoundsSource: lookahead must be >= 0 (path index units), got {lookahead}.")
            self._bounds = bounds
            self._clamp = clamp
            self._lookahead = float(lookahead)
            k = bounds.k
            self.path_index_input = self.DeclareVectorInputPort(name="path_index", size=1)
            self.bounds_input = self.DeclareAbstractInputPort(name="bounds", model_value=AbstractValue.Make(bounds))
            tickets = {self.path_index_input.ticket(), self.bounds_input.ticket()}
            # The three outputs share one lookup per path index (a cache entry).
            self._box = self.DeclareCacheEntry(
                description="(lower, upper, nominal, lower_ahead, upper_ahead) at the path index",
                value_producer=ValueProducer(
                    allocate=lambda: AbstractValue.Make(object()),
                    calc=lambda ctx, value: value.set_value(self._at(ctx)),
                ),
                prerequisites_of_calc=tickets,
            )
            # lower_output, upper_output, nominal_output, lower_ahead_output, upper_ahead_output.
            for i, port in enumerate(("lower", "upper", "nominal", "lower_ahead", "upper_ahead")):
                handle = self.DeclareVectorOutputPort(
                    name=port,
                    size=k,
                    calc=lambda ctx, out, i=i: out.SetFromVector(self._box.Eval(ctx)[i]),
                    prerequisites_of_calc=tickets,
                )
                setattr(self, f"{port}_output", handle)

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other._bounds, clamp=other._clamp, lookahead=other._lookahead, converter=converter)

        @property
        def bounds(self) -> BoundsTable:
            return self._bounds

        @property
        def lookahead(self) -> float:
            """L, path index units: how far ahead ``lower_ahead`` and ``upper_ahead`` look."""
            return self._lookahead

        def _lookup(self, s: float, bounds=None):
            bounds = self._bounds if bounds is None else bounds
            if self._clamp:
                s = min(max(s, 0.0), bounds.g - 1.0) if np.isfinite(s) else s
            return bounds.at(s)

        def _at(self, context):
            s_in = self.path_index_input.Eval(context)[0]
            live = self.bounds_input.Eval(context) if self.bounds_input.HasValue(context) else None
            if T is float:
                bounds = self._bounds if live is None else live
                if self._lookahead > 0 and isinstance(bounds, BoundsTable):  # one compiled call
                    s = float(s_in)
                    if self._clamp and np.isfinite(s):
                        s = min(max(s, 0.0), bounds.g - 1.0)
                    return bounds.box_ahead(s, self._lookahead)
                box = self._lookup(float(s_in), live)
                return tuple(box) + (self._ahead(float(s_in), box, live) if self._lookahead > 0 else tuple(box[:2]))
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
            out = tuple(
                np.array([AutoDiffXd(float(v), float(dv) * ds) for v, dv in zip(val, slope)], dtype=object)
                for val, slope in zip((lo, hi, nom), slopes)
            )
            return out + out[:2]

        def _ahead(self, s: float, box, live):
            """(lower, upper): the box at s tightened to the deviations the boxes allow over [s, s + lookahead]."""
            lo, hi, nom = box
            bounds = self._bounds if live is None else live
            end = min(s + self._lookahead, bounds.g - 1.0)
            if not np.isfinite(s) or end <= s:
                return lo, hi
            # Live bounds other than a table (a table takes BoundsTable.box_ahead): one lookup a sample.
            sigma = np.append(np.arange(np.floor(4.0 * s) + 1.0, np.ceil(4.0 * end)) / 4.0, end)
            lo_s, hi_s, nom_s = (np.array(a) for a in zip(*(bounds.at(float(x)) for x in sigma)))
            d_lo, d_hi = (lo_s - nom_s).max(axis=0), (hi_s - nom_s).min(axis=0)
            dev_lo, dev_hi = np.maximum(lo - nom, d_lo), np.minimum(hi - nom, d_hi)
            # About the nominal at s, never past the box at s (rounding).
            return np.clip(nom + np.minimum(dev_lo, 0.0), lo, hi), np.clip(nom + np.maximum(dev_hi, 0.0), lo, hi)

    return Impl


#: The float instantiation (``JointBoundsSource_[AutoDiffXd]`` by conversion).
JointBoundsSource = default_instantiation(JointBoundsSource_)
