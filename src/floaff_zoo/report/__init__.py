"""Reports and paper-style tables built from ``report.json`` files (see ``floaff-zoo table``)."""

from floaff_zoo.report.table import build_table, load_reports

__all__ = ["build_table", "load_reports"]
