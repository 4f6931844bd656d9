"""Contextweb's application layer: the web service, its CLI and dashboard."""
