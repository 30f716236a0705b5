"""Fields that only label: a file's name, a scene's name, the experiments' names. They name
things in messages and reports and never enter a traced program, so the program store's key
(`_programs.canonical`) leaves them out: one stored program serves every name."""

from __future__ import annotations

import equinox as eqx

#: the field metadata that marks a label
LABEL = "ppr_jax_label"


def label_field(**kwargs):
    """A static field that only labels (`eqx.field(static=True)` marked `LABEL`)."""
    return eqx.field(static=True, metadata={LABEL: True}, **kwargs)
