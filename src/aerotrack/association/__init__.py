"""Data association: local (MCMC tracklets in a sliding window) and global (tracklet linking)."""

from .local import LocalAssociator, associate

__all__ = ["LocalAssociator", "associate"]
