"""The concept web (§III-B): an MRF over concepts, settled by loopy belief propagation."""

from core.concept_web.web import ConceptWeb, WebInference, WebPotentials, loopy_belief_propagation

__all__ = ["ConceptWeb", "WebInference", "WebPotentials", "loopy_belief_propagation"]
