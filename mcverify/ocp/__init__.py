"""The optimal-control layer: the TO-CBF-MPC problem of the paper (box eq.tompc, eq.tompcAdd) as data.

Pure problem definition, no solving: :mod:`~mcverify.ocp.layout` (what the compiled code depends on,
the layouts of the decision and parameter vectors, packing and bounds), :mod:`~mcverify.ocp.problem`
(the maths: dynamics, VL-CBF constraints, objective, the CasADi NLP and its digest) and
:mod:`~mcverify.ocp.guess` (cold-start first guesses). The solver layer (:mod:`mcverify.solver`)
compiles and solves what is defined here.
"""

from mcverify.ocp.guess import initial_guess
from mcverify.ocp.layout import (
    CONSTRAINTS,
    N_FRONT,
    N_OPP,
    N_U,
    N_X,
    OPP_MODES,
    NlpLayout,
    OcpStructure,
    ParamLayout,
    constraint_bounds,
    decision_bounds,
    distance_margin,
    input_scale,
    opposing_mode,
    pack_params,
)
from mcverify.ocp.problem import FORMULATION_VERSION, build_nlp, formulation_digest

__all__ = [
    "CONSTRAINTS",
    "FORMULATION_VERSION",
    "N_FRONT",
    "N_OPP",
    "N_U",
    "N_X",
    "OPP_MODES",
    "NlpLayout",
    "OcpStructure",
    "ParamLayout",
    "build_nlp",
    "constraint_bounds",
    "decision_bounds",
    "distance_margin",
    "formulation_digest",
    "initial_guess",
    "input_scale",
    "opposing_mode",
    "pack_params",
]
