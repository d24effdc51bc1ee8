"""Co-manipulation runs: a scenario file -> a Drake diagram -> a recorded run.

A scenario (``diagrams/*.yaml``, loaded with ``yaml_load_typed``) has the
sections ``cell``, ``path``, ``bounds``, ``human``, ``control`` (the
systems' :class:`~drake_cfvol.systems.CoManipulationConfig` and the control
period), ``perception`` and ``simulation``.
:func:`build_comanipulation_diagram` plans the path, estimates the bounds,
adds the control chain with :func:`~drake_cfvol.systems.AddCoManipulation`
(the same call as in a user's station) and around it the scene, the
co-worker, the perception, the monitor and the loggers::

    PathProgress -> JointBoundsSource (ahead) -> AdmittanceDeformation <- ScriptedHuman
                              |                       | commanded_position
                              +-----------------> SafetyFilter <- query_object --+
                                                      | commanded_position        |
                              MultibodyPositionToGeometryPose -> SceneGraph ------+-> ClearanceMonitor

The robot follows the safety filter's ``commanded_position`` kinematically
(with ``control: {safety_filter: null}``, the admittance's). The diagram's own
SceneGraph holds the robot, the obstacles (coloured by category) and the
volume (its columns merged, conservatively, into at most 1500 boxes at any
R), all as proximity geometry; the clearance monitor asks it through its
query port, which the diagram also exports (``query_object``).

Modules: ``scenario`` (the file schema), ``checks`` (its values' checks), ``diagram`` (the diagram),
``run`` (simulate and summarise), ``report`` (plots, SVG), ``recording``
(Meshcat helpers), ``adversarial`` (steady pushes, the benchmark's
adversarial section; its patterns in ``push_patterns``). Imports ``systems``, ``algorithm``, ``scene``,
``kernel`` and ``io``.
"""

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the names as the type checker sees them
    from drake_cfvol.comanip.diagram import (
        MAX_PROXIMITY_BOXES,
        UPDATE_RATE_LOGS,
        CoManipulation,
        build_comanipulation_diagram,
        frame_camera,
        meshcat_params,
        show_category_legend,
    )
    from drake_cfvol.comanip.report import missing_dot_notice, plot_run, write_diagram_svg
    from drake_cfvol.comanip.run import MARGIN_TOLERANCE, run_problems, run_scenario, update_rate_figures
    from drake_cfvol.comanip.run_summary import OnlineFigures, RunSummary, TrackingFigures
    from drake_cfvol.comanip.scenario import (
        BoundsConfig,
        CellConfig,
        ControlConfig,
        HumanConfig,
        PathConfig,
        PerceptionSection,
        RandomPushes,
        Reactive,
        Scenario,
        SimulationConfig,
        diagrams_dir,
        load_scenario,
        validate_scenario,
    )
    from drake_cfvol.io.style import CATEGORY_COLOURS

#: The public names, each with its module: imported on first use (PEP 562), so that a
#: module of this package that needs no Drake (:mod:`.push_patterns`, which the CLI's
#: ``--help`` reads) loads none.
_LAZY = {
    "MAX_PROXIMITY_BOXES": "drake_cfvol.comanip.diagram",
    "UPDATE_RATE_LOGS": "drake_cfvol.comanip.diagram",
    "CoManipulation": "drake_cfvol.comanip.diagram",
    "build_comanipulation_diagram": "drake_cfvol.comanip.diagram",
    "frame_camera": "drake_cfvol.comanip.diagram",
    "meshcat_params": "drake_cfvol.comanip.diagram",
    "show_category_legend": "drake_cfvol.comanip.diagram",
    "missing_dot_notice": "drake_cfvol.comanip.report",
    "plot_run": "drake_cfvol.comanip.report",
    "write_diagram_svg": "drake_cfvol.comanip.report",
    "MARGIN_TOLERANCE": "drake_cfvol.comanip.run",
    "run_problems": "drake_cfvol.comanip.run",
    "run_scenario": "drake_cfvol.comanip.run",
    "update_rate_figures": "drake_cfvol.comanip.run",
    "OnlineFigures": "drake_cfvol.comanip.run_summary",
    "RunSummary": "drake_cfvol.comanip.run_summary",
    "TrackingFigures": "drake_cfvol.comanip.run_summary",
    "BoundsConfig": "drake_cfvol.comanip.scenario",
    "CellConfig": "drake_cfvol.comanip.scenario",
    "ControlConfig": "drake_cfvol.comanip.scenario",
    "HumanConfig": "drake_cfvol.comanip.scenario",
    "PathConfig": "drake_cfvol.comanip.scenario",
    "PerceptionSection": "drake_cfvol.comanip.scenario",
    "RandomPushes": "drake_cfvol.comanip.scenario",
    "Reactive": "drake_cfvol.comanip.scenario",
    "Scenario": "drake_cfvol.comanip.scenario",
    "SimulationConfig": "drake_cfvol.comanip.scenario",
    "diagrams_dir": "drake_cfvol.comanip.scenario",
    "load_scenario": "drake_cfvol.comanip.scenario",
    "validate_scenario": "drake_cfvol.comanip.scenario",
    "CATEGORY_COLOURS": "drake_cfvol.io.style",
}


def __getattr__(name: str) -> object:
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value  # later lookups skip this function
        return value
    try:
        return importlib.import_module(f"{__name__}.{name}")
    except ModuleNotFoundError:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


__all__ = [
    "CellConfig",
    "PathConfig",
    "BoundsConfig",
    "HumanConfig",
    "ControlConfig",
    "PerceptionSection",
    "SimulationConfig",
    "RandomPushes",
    "Reactive",
    "Scenario",
    "load_scenario",
    "validate_scenario",
    "diagrams_dir",
    "CoManipulation",
    "build_comanipulation_diagram",
    "frame_camera",
    "show_category_legend",
    "meshcat_params",
    "UPDATE_RATE_LOGS",
    "MAX_PROXIMITY_BOXES",
    "run_scenario",
    "RunSummary",
    "OnlineFigures",
    "TrackingFigures",
    "run_problems",
    "update_rate_figures",
    "MARGIN_TOLERANCE",
    "plot_run",
    "missing_dot_notice",
    "write_diagram_svg",
    "CATEGORY_COLOURS",
]
