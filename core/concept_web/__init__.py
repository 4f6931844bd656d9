"""The concept web (§III-B): an MRF over concepts, settled by loopy belief propagation."""

from core.concept_web.web import DEFAULT_DAMPING, ConceptWeb, WebInference, WebPotentials, loopy_belief_propagation

__all__ = ["DEFAULT_DAMPING", "ConceptWeb", "WebInference", "WebPotentials", "loopy_belief_propagation"]
