"""DepthSplat's released checkpoints in prosplat: an independent implementation of its encoder
(read from cvg/depthsplat at commit 2dad25a, MIT; no code copied), checked against the
reference by the parity fixtures under tests/fixtures/depthsplat/.

- :func:`load_depthsplat` reads a released ``.pth`` and returns a :class:`DepthSplatEncoder`
  whose :meth:`~DepthSplatEncoder.forward_reference` speaks DepthSplat's conventions;
- :class:`DepthSplatGenerator` wraps it behind prosplat's generator interface
  (``ProSplat.from_pretrained(generator=PATH)``).
"""

from prosplat.generator.depthsplat.config import (
    LICENCES,
    REFERENCE_COMMIT,
    RELEASED,
    DepthSplatConfig,
)
from prosplat.generator.depthsplat.load import (
    load_depthsplat,
    random_encoder,
    random_state_dict,
    save_released_format,
)
from prosplat.generator.depthsplat.model import DepthSplatEncoder
from prosplat.generator.depthsplat.wrapper import DepthSplatGenerator

__all__ = [
    "LICENCES",
    "REFERENCE_COMMIT",
    "RELEASED",
    "DepthSplatConfig",
    "DepthSplatEncoder",
    "DepthSplatGenerator",
    "load_depthsplat",
    "random_encoder",
    "random_state_dict",
    "save_released_format",
]
