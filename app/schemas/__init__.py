"""Request and response schemas (pydantic v2), in families: ``XCreate`` in, ``XRead`` out."""
