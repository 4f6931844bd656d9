"""Planning in context (§V-E): the learned behaviour effects, pruned by P(verb | χ) of the chosen context."""

from __future__ import annotations

from typing import TypedDict

from sqlalchemy.orm import Session

from app.errors import InvalidInput, ModelNotFitted, SceneNotFound
from app.registry import ModelRuntime
from app.schemas.plans import PlanCreate, PlanRead, SearchCount
from app.services import scenes as scene_service
from core.planning import PlanResult, plan, plan_in_context, verb_given_context_from_model
from storage.repositories import scenes as scene_repository


class _Search(TypedDict):
    """The search settings both planners take (core.planning.plan, plan_in_context)."""

    mode: str
    node_budget: int
    depth_budget: int


def make_plan(session: Session, model: ModelRuntime, body: PlanCreate) -> PlanRead:
    effects = model.effects
    if effects is None:
        raise ModelNotFitted(model.id, "behaviour effects (fit with training objects that have effects)")
    if body.object in body.obstacles:
        raise InvalidInput(f"obstacles.{body.object}", "the object to move cannot also be an obstacle")
    table = {body.object: body.start, **body.obstacles}
    budgets: _Search = {"mode": body.mode, "node_budget": body.node_budget, "depth_budget": body.depth_budget}
    unpruned = _checked(plan(effects, table, body.object, body.goal, **budgets))
    context, source = _context(session, model, body)
    if context is None:
        return _plan_read(unpruned, unpruned, None, source, None)
    with model.lock:
        lda = model.incremental_lda
        if context >= lda.n_contexts:
            raise InvalidInput("context", f"the model has {lda.n_contexts} context(s): 0 … {lda.n_contexts - 1}")
        phi = lda.concept_given_context()
        concepts = lda.vocabulary
    verbs = list(effects.behaviours)
    verb_given_context = dict(
        zip(verbs, verb_given_context_from_model(phi, concepts, verbs)[context].tolist(), strict=True)
    )
    pruned = _checked(plan_in_context(effects, table, body.object, body.goal, verb_given_context, **budgets))
    return _plan_read(pruned, unpruned, context, source, verb_given_context)


def _context(session: Session, model: ModelRuntime, body: PlanCreate) -> tuple[int | None, str]:
    if body.context is not None:
        return body.context, "given"
    if body.scene_id is not None:
        row = scene_repository.get_scene(session, model.id, body.scene_id)
        if row is None:
            raise SceneNotFound(model.id, body.scene_id)
        return row.map_context, "scene"
    if body.scene is not None:
        return scene_service.infer_scene(model, body.scene).map_context, "inferred"
    return None, "none"


def _checked(result: PlanResult) -> PlanResult:
    if result.status == "invalid":
        raise InvalidInput(result.field or "body", result.message)
    return result


def _plan_read(
    result: PlanResult,
    unpruned: PlanResult,
    context: int | None,
    source: str,
    verb_given_context: dict[str, float] | None,
) -> PlanRead:
    return PlanRead(
        status=result.status,
        mode=result.mode,
        context=context,
        context_source=source,
        plan=list(result.plan),
        positions=list(result.positions),
        kept=list(result.kept),
        pruned=list(result.pruned),
        verb_given_context=verb_given_context,
        nodes_expanded=result.nodes_expanded,
        nodes_generated=result.nodes_generated,
        unpruned=SearchCount(
            status=unpruned.status, nodes_expanded=unpruned.nodes_expanded, nodes_generated=unpruned.nodes_generated
        ),
    )
