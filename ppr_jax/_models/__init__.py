"""The model levels of MODEL.md section 5, one file each, and their registry.

To add a level: a final subclass of `AbstractModel` (or `AbstractDouble1R`) in a new file here,
and one line in `MODELS`. Scenes, the CLI's `--model` choices and the benchmarks read `MODELS`.
"""

from __future__ import annotations

from typing import Optional, Union

from .._checks import PPRError, check_number
from .base import AbstractModel as AbstractModel, Kin as Kin
from .beam import Beam as Beam
from .double1r import AbstractDouble1R as AbstractDouble1R, Double1R as Double1R
from .reduced import Reduced as Reduced
from .rigid import Rigid as Rigid

#: name -> model class, in order of fidelity (L0 ... L3)
MODELS: dict[str, type[AbstractModel]] = {
    Rigid.name: Rigid,
    Reduced.name: Reduced,
    Double1R.name: Double1R,
    Beam.name: Beam,
}

#: beam elements per strip of L3 when none is given, and the most allowed
DEFAULT_ELEMENTS = 8
MAX_ELEMENTS = 256


def get_model(model: Union[str, AbstractModel], n_elements: Optional[int] = None) -> AbstractModel:
    """A model from its name (see `MODELS`: rigid, reduced, double1r, beam) or an instance;
    `n_elements` is the number of beam elements per strip of `beam` (default 8)."""
    if isinstance(model, AbstractModel):
        return model
    cls = MODELS.get(str(model))
    if cls is None:
        raise PPRError(f"unknown model {model!r}; allowed: {', '.join(MODELS)}")
    if cls is Beam:
        n = DEFAULT_ELEMENTS if n_elements is None else n_elements
        # The state grows as 3 + 3N and the compiled right-hand side as N^2: above 256 elements
        # (773 coordinates) compilation alone takes hours, and the model has long converged.
        n = check_number("elements (beam elements per strip of L3)", n, 2, MAX_ELEMENTS,
                         integer=True)
        return Beam(n)
    return cls()
