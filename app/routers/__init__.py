"""Thin routers: validate, call one service function, return a schema."""
