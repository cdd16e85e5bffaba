"""The LPIPS weights in float16 for a lent GPU machine's bounded carry, and back.

A call to the machine carries at most 64 MiB with the working tree; the float32 weights take
10 MB of it, float16 5 MB. Training needs float32 there (LPIPS is a loss), so the GPU scripts
widen them on arrival. The metadata (where the weights come from) travels unchanged.

    python scripts/gpu_lpips.py pack DIR     # here: $PROSPLAT_CACHE's weights -> DIR/*.f16.safetensors
    python scripts/gpu_lpips.py unpack DIR   # there: DIR/*.f16.safetensors -> $PROSPLAT_CACHE
                                             # (none there: a note, the cache is left as it is)
"""

from __future__ import annotations

import sys
from pathlib import Path

from safetensors import safe_open
from safetensors.torch import load_file, save_file

NAME = "lpips_alex_v0.1.safetensors"


def _convert(src: Path, dst: Path, half: bool) -> None:
    with safe_open(str(src), "pt") as f:
        meta = f.metadata()
    tensors = {k: v.half() if half else v.float() for k, v in load_file(str(src)).items()}
    dst.parent.mkdir(parents=True, exist_ok=True)
    save_file(tensors, str(dst), metadata=meta)


def main(argv: list[str]) -> int:
    from prosplat.core.paths import cache_dir

    if len(argv) != 2 or argv[0] not in ("pack", "unpack"):
        print(__doc__, file=sys.stderr)
        return 2
    folder = Path(argv[1])
    f16 = folder / NAME.replace(".safetensors", ".f16.safetensors")
    if argv[0] == "pack":
        src = cache_dir() / NAME
        if not src.is_file():
            print(f"no LPIPS weights at {src}: run `make setup` first", file=sys.stderr)
            return 1
        _convert(src, f16, half=True)
    elif f16.is_file():
        _convert(f16, cache_dir() / NAME, half=False)
    else:  # the cache may hold the weights already (a warm machine, a dry run here)
        print(f"gpu_lpips.py: no {f16}; LPIPS reads {cache_dir() / NAME}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
