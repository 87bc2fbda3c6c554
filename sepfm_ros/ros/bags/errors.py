"""The bag errors: each carries a message meant for the user (no traceback needed)."""

from __future__ import annotations


class BagError(Exception):
    """A bag problem with a message meant for the user (no traceback needed)."""


class BagNotFoundError(BagError):
    """The bag path does not exist or is not a bag."""


class BagCorruptError(BagError):
    """The bag's metadata or storage cannot be read (truncated, corrupt, unsupported)."""


class TopicNotFoundError(BagError):
    """A requested topic is not in the bag."""


class UnknownTypeError(BagError):
    """A message type is not known (not a ROS 2 Jazzy type) or not the type that was expected."""


class StampOrderError(BagError):
    """Header stamps of a topic go backwards or repeat."""


class OutputExistsError(BagError):
    """The output path exists already; nothing is overwritten."""
