"""The one error type of `prosplat.poses`, in its own module so every poses module can raise it."""


class PoseError(ValueError):
    """One line an artist can act on: how many photos matched and what to do."""
