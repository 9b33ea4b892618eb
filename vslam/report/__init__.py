"""vslam.report: self-contained HTML reports of a run folder or a benchmark folder."""
from vslam.report.html import bench_report_html, load_run, run_report_html, write_report

__all__ = ["bench_report_html", "load_run", "run_report_html", "write_report"]
