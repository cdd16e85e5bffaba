"""The error types of `prosplat.poses`, in their own module so every poses module can raise them."""


class PoseError(ValueError):
    """One line an artist can act on: how many photos matched and what to do."""


class PoseCancelled(PoseError):
    """The user cancelled; whatever the step had written is removed."""


def require(module: object, package: str) -> None:
    """Raise a one-line :class:`PoseError` when ``module`` (an optional import) is missing.

    The SfM, image and video libraries are imported where the poses modules load, which the
    command line does to build its ``poses`` parser; a training-only machine (a lent GPU that
    gets only the wheels ``scripts/gpu_*`` carry) has none of them and still runs
    ``prosplat train``. Only the calls that need one fail, and they say what to install."""
    if module is None:
        raise PoseError(
            f"this step needs {package}, which this Python lacks: pip install {package}"
        )
