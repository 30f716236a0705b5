"""The model levels of MODEL.md section 5, one file each, and their registry.

To add a level: a final subclass of `AbstractModel` (or `AbstractDouble1R`) in a new file here,
one line in `MODELS`, and its name in `_names.MODEL_NAMES` (which the CLI's parser reads
without importing JAX; tests/test_imports.py checks the two agree). Scenes, the CLI and the
benchmarks read `MODELS`.
"""

from __future__ import annotations

from typing import Optional, Union

from .._errors import PPRError, check_number
from .._names import (
    DEFAULT_ELEMENTS as DEFAULT_ELEMENTS,
    MAX_ELEMENTS as MAX_ELEMENTS,
    STRIP_DYNAMICS as STRIP_DYNAMICS,
)
from .base import (
    AbstractClosedLoop as AbstractClosedLoop,
    AbstractModel as AbstractModel,
    Kin as Kin,
    Motion as Motion,
)
from .beam import AbstractBeam as AbstractBeam, Beam as Beam
from .beam_qs import QuasiStaticBeam as QuasiStaticBeam
from .double1r import AbstractDouble1R as AbstractDouble1R, Double1R as Double1R
from .reduced import Reduced as Reduced
from .rigid import Rigid as Rigid

#: name -> model class, in order of fidelity (L0 ... L3)
MODELS: dict[str, type[AbstractModel]] = {
    Rigid.name: Rigid,
    Reduced.name: Reduced,
    Double1R.name: Double1R,
    QuasiStaticBeam.name: QuasiStaticBeam,
}


def get_model(
    model: Union[str, AbstractModel],
    n_elements: Optional[int] = None,
    strip_dynamics: str = "quasi-static",
    strip_loss: float = 0.0,
) -> AbstractModel:
    """A model from its name (see `MODELS`: rigid, reduced, double1r, beam) or an instance.

    **Arguments:**

    - `model`: a name in `MODELS` or an `AbstractModel` (returned as it is).
    - `n_elements`: the number of beam elements per strip of `beam` (default 8, from 2 to 256);
      ignored by the other models.
    - `strip_dynamics`: how the strips of `beam` move: `quasi-static` (`QuasiStaticBeam`, 9
      coordinates, the default) or `full` (`Beam`, 3 + 3N coordinates with the strips' own
      modes: stiff).
    - `strip_loss`: the full beam's Kelvin-Voigt retardation time (s, default 0; `Beam`).

    **Returns:**

    An `AbstractModel`.

    **Raises:**

    `PPRError` for an unknown name or `strip_dynamics`, `n_elements` out of range, or a positive
    `strip_loss` with quasi-static strips (which have no strip modes to damp).
    """
    if isinstance(model, AbstractModel):
        return model
    # the levels without options are built once (an immutable module; building one took
    # 25-60 us of a warm scene call on a 2-core CPU)
    key = (model, n_elements, strip_dynamics, strip_loss)
    try:
        cached = isinstance(model, str) and hash(key) is not None
    except TypeError:  # an array for a number: `_build`'s checks name the parameter
        cached = False
    hit = _BUILT.get(key) if cached else None
    if hit is not None:
        return hit
    out = _build(model, n_elements, strip_dynamics, strip_loss)
    if cached and len(_BUILT) < 64:
        _BUILT[key] = out
    return out


#: models built by name (`get_model`), keyed by its arguments
_BUILT: dict = {}


def _build(model, n_elements, strip_dynamics, strip_loss) -> AbstractModel:
    cls = MODELS.get(str(model))
    if cls is None:
        raise PPRError(f"unknown model {model!r}; allowed: {', '.join(MODELS)}")
    if strip_dynamics not in STRIP_DYNAMICS:
        raise PPRError(f"strip_dynamics must be one of {', '.join(STRIP_DYNAMICS)}, got "
                       f"{strip_dynamics!r}")
    if cls is QuasiStaticBeam:
        n = DEFAULT_ELEMENTS if n_elements is None else n_elements
        # The state grows as 3 + 3N and the compiled right-hand side as N^2: above 256 elements
        # (773 coordinates) compilation alone takes hours, and the model has long converged.
        n = check_number("elements (beam elements per strip of L3)", n, 2, MAX_ELEMENTS,
                         integer=True)
        if strip_dynamics == "full":
            return Beam(n, strip_loss=strip_loss)
        if strip_loss != 0:
            raise PPRError(f"strip_loss = {strip_loss!r} s needs strip_dynamics 'full' (the "
                           "quasi-static strips have no strip modes to damp); use 0 or full")
        return QuasiStaticBeam(n)
    return cls()
