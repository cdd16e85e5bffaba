"""The error types of `prosplat.poses`, in their own module so every poses module can raise them."""


class PoseError(ValueError):
    """One line an artist can act on: how many photos matched and what to do."""


class PoseCancelled(PoseError):
    """The user cancelled; whatever the step had written is removed."""
