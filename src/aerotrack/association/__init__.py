"""Data association: local (MCMC tracklets within a sliding window) and global (tracklet linking)."""

from .local import LocalAssociator, associate

__all__ = ["LocalAssociator", "associate"]
