"""The bases every schema builds on, the error body and the page of a listing."""

from __future__ import annotations

from typing import Annotated, Any, Generic, TypeVar

from pydantic import BaseModel, ConfigDict, Discriminator, Field, Tag

T = TypeVar("T")

#: Tags of the two-shape unions below; they are left out of the field names of errors.
AS_LIST, AS_MAP, AS_BASE64 = "as list", "as map", "as base64"
#: Tags of the K rule's union (app/schemas/models.py), told apart by its ``name``.
SCENES_RULE, PAPER_RULE = "scenes rule", "paper rule"
UNION_TAGS = frozenset({AS_LIST, AS_MAP, AS_BASE64, SCENES_RULE, PAPER_RULE})


def _shape(value: Any) -> str:
    if isinstance(value, dict):
        return AS_MAP
    return AS_BASE64 if isinstance(value, str) else AS_LIST


Names = TypeVar("Names")
Probabilities = TypeVar("Probabilities")
Array = TypeVar("Array")
Base64 = TypeVar("Base64")


def _by_shape(error_type: str, takes: str) -> Discriminator:
    """The union's member picked by the JSON shape (:func:`_shape`); any other shape is refused
    with what the field takes, not with pydantic's tag names."""
    return Discriminator(_shape, custom_error_type=error_type, custom_error_message=f"Input should be {takes}")


#: ``ListOrMap[Names, Probabilities]``: ``Names | Probabilities`` told apart by the JSON shape (array or object).
ListOrMap = Annotated[
    Annotated[Names, Tag(AS_LIST)] | Annotated[Probabilities, Tag(AS_MAP)],
    _by_shape("list_or_map_type", "an array of names or an object of names to probabilities"),
]
#: ``ArrayOrBase64[Array, Base64]``: ``Array | Base64`` told apart by the JSON shape (array or string).
ArrayOrBase64 = Annotated[
    Annotated[Array, Tag(AS_LIST)] | Annotated[Base64, Tag(AS_BASE64)],
    _by_shape("array_or_base64_type", "a JSON array or a base64 string of little-endian float32 values"),
]


#: No control characters: a name or label stored in the database (PostgreSQL text refuses NUL).
NO_CONTROL_CHARACTERS = r"^[^\x00-\x1f\x7f]+$"
#: Printable ASCII without spaces: a header token such as an Idempotency-Key.
PRINTABLE_ASCII = r"^[\x21-\x7e]+$"
#: What a refused pattern means, said in the error instead of the regular expression (app/errors.py).
PATTERN_MEANINGS = {
    NO_CONTROL_CHARACTERS: "String should contain no control characters (U+0000 to U+001F, U+007F)",
    PRINTABLE_ASCII: "String should be printable ASCII without spaces (the characters ! to ~)",
}

#: A probability in [0, 1].
Probability = Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)]
#: A finite real number (NaN and ±inf are refused with a 422 naming the field).
FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]


class ReadSchema(BaseModel):
    """Base of the responses: built from ORM rows or service results."""

    model_config = ConfigDict(from_attributes=True, protected_namespaces=())


class RequestSchema(BaseModel):
    """Base of the request bodies: unknown fields are a 422, not silently dropped, and so is a value
    of another JSON type than the field's, which pydantic's lax mode would convert (``true`` or
    ``"0.5"`` for a probability, ``"12"`` for a count): strict mode. A whole number is still a
    number (``1`` for a probability); a field typed as a tuple says ``Field(strict=False)``, since
    JSON has only arrays."""

    model_config = ConfigDict(extra="forbid", protected_namespaces=(), strict=True)


class ErrorRead(ReadSchema):
    """Every error body: a machine-readable ``error``, a sentence, and the offending field."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "error": "invalid_input",
                    "detail": "objects[0].features.entity: List should have at least 91 items after validation, not 3",
                    "field": "objects[0].features.entity",
                }
            ]
        }
    )

    error: str = Field(description="Kind of error, e.g. `model_not_found`, `invalid_input`.")
    detail: str = Field(description="What went wrong, for a human.")
    field: str | None = Field(None, description="The request field at fault, when there is one.")


class Page(ReadSchema, Generic[T]):
    """One page of a listing, oldest first."""

    items: list[T]
    total: int = Field(description="Number of items in the whole listing.")
    offset: int
    limit: int
