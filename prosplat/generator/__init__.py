"""Stage 1: the feed-forward Gaussian generator (DepthSplat-style), see :class:`Generator`."""

from prosplat.generator.config import BASE, PRESETS, TINY, GeneratorConfig, preset
from prosplat.generator.model import Generator
from prosplat.generator.output import GeneratorOutput

__all__ = ["BASE", "PRESETS", "TINY", "Generator", "GeneratorConfig", "GeneratorOutput", "preset"]
