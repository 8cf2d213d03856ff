"""Type stubs of the extension module (python/src/*.rs). The public API is re-exported by
``facepose`` (``__init__.py``, typed inline); the underscored names are its plumbing."""

from os import PathLike
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

DEFAULT_DT: float
MAX_NAME: int

class FaceposeError(ValueError):
    """What facepose refuses; the message is the service's 422 message for the same input."""

class NonFiniteError(FaceposeError): ...
class TooFewPointsError(FaceposeError): ...
class PointCountError(FaceposeError): ...
class DegenerateError(FaceposeError): ...
class InvalidParameterError(FaceposeError): ...
class InvalidSchemeError(FaceposeError): ...
class NotAFaceError(FaceposeError): ...
class NumericalError(FaceposeError): ...
class ConventionError(FaceposeError): ...
class ModelError(FaceposeError): ...

_Camera = Optional[Tuple[float, float, float, float]]
_Size = Optional[Tuple[float, float]]

class Model:
    """A pose model: ``Model.default()``, ``Model.load(path)`` or ``facepose.train(shapes)``."""

    @staticmethod
    def default() -> Model:
        """The embedded default model (parsed once per process)."""
    @staticmethod
    def load(path: Union[str, PathLike[str]]) -> Model:
        """A model bundle: a folder with model.json, or the file. Raises ModelError."""
    def save(self, path: Union[str, PathLike[str]]) -> None:
        """Writes the bundle to the folder ``path`` (which must not exist), atomically."""
    @property
    def name(self) -> str: ...
    @property
    def version(self) -> str: ...
    @property
    def schemes(self) -> List[Tuple[str, int]]:
        """The schemes served and their point counts, the model's own first."""
    def scheme_points(self, scheme: str) -> List[str]:
        """The point names of a scheme, in order."""
    def mean_shape(self, scheme: str) -> npt.NDArray[np.float64]:
        """The mean 3D shape in a scheme, (N, 3) mm, model frame: a generic face."""
    @property
    def has_shape_basis(self) -> bool: ...
    @property
    def has_calibration(self) -> bool: ...
    def to_json(self) -> str:
        """The bundle as JSON text."""
    def _estimate_one(
        self,
        landmarks: npt.NDArray[np.float64],
        scheme: Optional[str] = ...,
        method: Optional[str] = ...,
        landmark_style: Optional[str] = ...,
        camera: _Camera = ...,
        image_size: _Size = ...,
        conventions: Optional[str] = ...,
    ) -> Dict[str, Any]: ...
    def _estimate_array(
        self,
        landmarks: npt.NDArray[np.float64],
        scheme: Optional[str] = ...,
        method: Optional[str] = ...,
        landmark_style: Optional[str] = ...,
        camera: _Camera = ...,
        image_size: _Size = ...,
        conventions: Optional[str] = ...,
        threads: Optional[int] = ...,
    ) -> Dict[str, Any]: ...
    def _estimate_list(
        self,
        landmarks: Sequence[npt.NDArray[np.float64]],
        scheme: Optional[str] = ...,
        method: Optional[str] = ...,
        landmark_style: Optional[str] = ...,
        camera: _Camera = ...,
        image_size: _Size = ...,
        conventions: Optional[str] = ...,
        threads: Optional[int] = ...,
    ) -> Dict[str, Any]: ...

class _Tracker:
    def __init__(self, kind: str, params: Dict[str, float], max_gap: float) -> None: ...
    @property
    def kind(self) -> str: ...
    def filter(
        self,
        key: str,
        rotation: npt.NDArray[np.float64],
        turn_cov: Optional[npt.NDArray[np.float64]],
        t: Optional[float],
    ) -> Tuple[npt.NDArray[np.float64], float, float, float, bool]: ...
    def forget(self, key: str) -> bool: ...
    def reset(self) -> None: ...
    def tracks(self) -> List[str]: ...

def _train(
    shapes: npt.NDArray[np.float64],
    created: str,
    scheme: str = ...,
    components: int = ...,
    grid: str = ...,
    subsets: Optional[List[str]] = ...,
    seed: int = ...,
    name: str = ...,
    version: str = ...,
) -> Model: ...
