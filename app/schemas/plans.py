"""Planning in context (§V-E): move one object over the table, behaviours pruned by the context."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import ConfigDict, Field, model_validator

from app.schemas.common import ReadSchema, RequestSchema
from app.schemas.observations import Name
from app.schemas.scenes import SceneCreate

MAX_NODE_BUDGET = 1_000_000
MAX_DEPTH_BUDGET = 64


class PlanCreate(RequestSchema):
    """Bring ``object`` from ``start`` to ``goal``; the context is given, read from a learned scene,
    or inferred from a scene posted here (at most one of the three; none means no pruning)."""

    model_config = ConfigDict(json_schema_extra={"examples": [{"object": "cup", "start": 8, "goal": 5, "context": 0}]})

    object: Name = Field(description="Name of the object to move (a label; it need not be a concept).")
    start: int = Field(ge=1, le=10_000, description="Its position (Fig. 15(a) numbering).")
    goal: int = Field(ge=1, le=10_000)
    obstacles: dict[Name, int] = Field(default_factory=dict, max_length=100, description="Other objects' positions.")
    context: int | None = Field(None, ge=0, le=1_000, description="The context χ, given.")
    scene_id: int | None = Field(None, ge=0, le=2**31 - 1, description="A learned scene whose MAP context to use.")
    scene: SceneCreate | None = Field(None, description="A scene to infer the context from (not learned).")
    mode: Literal["paper", "bfs", "astar"] = Field(
        "astar", description="paper: full breadth-first tree (the paper's node count); bfs; astar."
    )
    node_budget: int = Field(MAX_NODE_BUDGET, ge=1, le=MAX_NODE_BUDGET)
    depth_budget: int = Field(MAX_DEPTH_BUDGET, ge=0, le=MAX_DEPTH_BUDGET)

    @model_validator(mode="before")
    @classmethod
    def _one_context_source(cls, values: Any) -> Any:
        if isinstance(values, dict):
            given = [name for name in ("context", "scene_id", "scene") if values.get(name) is not None]
            if len(given) > 1:
                raise ValueError(f"give at most one of context, scene_id, scene (got {', '.join(given)})")
        return values


class SearchCount(ReadSchema):
    status: Literal["solved", "unreachable", "budget_exceeded"]
    nodes_expanded: int
    nodes_generated: int = Field(description="Tree nodes created, root included (what Fig. 16 plots).")


class PlanRead(ReadSchema):
    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "status": "solved",
                    "mode": "paper",
                    "context": 0,
                    "context_source": "given",
                    "plan": ["move_right", "move_right", "move_right"],
                    "positions": [8, 7, 6, 5],
                    "kept": ["grasp", "move_left", "move_right", "move_forward", "move_backward"],
                    "pruned": [
                        "push_left",
                        "push_right",
                        "push_forward",
                        "push_backward",
                        "drop",
                        "throw",
                        "knock_down",
                        "shake",
                    ],
                    "verb_given_context": {"grasp": 0.2},
                    "nodes_expanded": 31,
                    "nodes_generated": 156,
                    "unpruned": {"status": "solved", "nodes_expanded": 183, "nodes_generated": 2380},
                }
            ]
        }
    )

    status: Literal["solved", "unreachable", "budget_exceeded"]
    mode: str
    context: int | None
    context_source: Literal["given", "scene", "inferred", "none"]
    plan: list[str]
    positions: list[int] = Field(description="The object's positions along the plan, start first.")
    kept: list[str]
    pruned: list[str]
    verb_given_context: dict[str, float] | None = Field(description="P(verb | χ) that decided the pruning.")
    nodes_expanded: int
    nodes_generated: int
    unpruned: SearchCount = Field(description="The same search with every behaviour, for comparison.")
