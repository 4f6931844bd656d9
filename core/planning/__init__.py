"""Planning in context (§V-E, Figs. 15–16): learned effects, context-dependent pruning, forward planners.

See docs/planning.md for the workspace, the pruning rule and the node-counting conventions.
"""

from core.planning.effects import FALL_HEIGHT, BehaviourEffects, learn_effects
from core.planning.planners import DEPTH_BUDGET, MODES, NODE_BUDGET, PlanResult, plan, plan_in_context
from core.planning.pruning import (
    PRUNING_THRESHOLD,
    Pruning,
    prune_behaviours,
    verb_given_context_from_model,
    verb_given_context_from_scenes,
    verb_given_context_from_world,
)
from core.planning.workspace import OFF_TABLE, Workspace

__all__ = [
    "DEPTH_BUDGET",
    "FALL_HEIGHT",
    "MODES",
    "NODE_BUDGET",
    "OFF_TABLE",
    "PRUNING_THRESHOLD",
    "BehaviourEffects",
    "PlanResult",
    "Pruning",
    "Workspace",
    "learn_effects",
    "plan",
    "plan_in_context",
    "prune_behaviours",
    "verb_given_context_from_model",
    "verb_given_context_from_scenes",
    "verb_given_context_from_world",
]
