"""Reports: the self-contained HTML study report."""

from tofmetry.report._html import ComparisonRow, Report, Section, render_html

__all__ = ["ComparisonRow", "Report", "Section", "render_html"]
