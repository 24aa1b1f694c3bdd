"""``oprecon remesh``: particles on an existing mesh (S&T92 §9), see :mod:`.pipeline`."""

from .pipeline import RemeshOptions, RemeshResult, remesh, remesh_file, report_path_for

__all__ = ["RemeshOptions", "RemeshResult", "remesh", "remesh_file", "report_path_for"]
