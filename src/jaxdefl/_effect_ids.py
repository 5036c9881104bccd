"""The effect ids of the DIAG.json contract, derived from the vocabulary (`jaxdefl.effects`);
kept for the modules that import them from here."""

from .effects import EFFECT_IDS

__all__ = ["EFFECT_IDS"]
