# Types of the native module; the documented functions are in __init__.py.
from typing import Callable, Dict, List, Optional, Sequence, Union
import os

import numpy as np

__version__: str

class Error(ValueError): ...
class Cancelled(Error): ...

class CancelToken:
    def __init__(self) -> None: ...
    def cancel(self) -> None: ...
    @property
    def cancelled(self) -> bool: ...

def denoise(
    color: np.ndarray,
    albedo: Optional[np.ndarray] = None,
    normal: Optional[np.ndarray] = None,
    depth: Optional[np.ndarray] = None,
    *,
    material: Optional[np.ndarray] = None,
    shadow: Optional[np.ndarray] = None,
    variance: Optional[np.ndarray] = None,
    color_a: Optional[np.ndarray] = None,
    color_b: Optional[np.ndarray] = None,
    pipeline: str = "full",
    seed: int = 0,
    threads: Optional[int] = None,
    progress: Optional[Callable[[float, str], Optional[bool]]] = None,
    cancel: Optional[CancelToken] = None,
    set: Optional[Sequence[str]] = None,
) -> np.ndarray: ...
def read_render(
    path: Union[str, os.PathLike], maps: Optional[Dict[str, str]] = None
) -> Dict[str, np.ndarray]: ...
def pipelines() -> List[str]: ...
