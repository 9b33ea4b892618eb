"""Open the reports in headless Chromium: the page loads without script errors and every image decodes."""
from __future__ import annotations

import re
import shutil
import subprocess

import pytest

from vslam.bench.fake import fake_run
from vslam.report.html import write_report

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


def dump_dom(html_path, tmp_path) -> str:
    """The DOM after the page's load event (our inline script has run by then)."""
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
           "--disable-component-update", "--disable-sync", "--no-first-run", "--disable-extensions",
           f"--user-data-dir={tmp_path / 'chromium-profile'}", "--virtual-time-budget=5000",
           "--dump-dom", html_path.resolve().as_uri()]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=90)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout


@pytest.mark.skipif(CHROMIUM is None, reason="chromium not installed (Debian package `chromium`; CI installs it)")
def test_run_report_renders_in_chromium(tmp_path):
    run = tmp_path / "run"
    fake_run("nowhere", run, sensor="rgbd", max_frames=20)
    page = write_report(run, tmp_path / "report.html")
    dom = dump_dom(page, tmp_path)
    body = re.search(r"<body[^>]*>", dom).group(0)
    assert 'data-images-total="4"' in body and 'data-images-ok="4"' in body, body
    assert 'data-script-errors="0"' in body and 'data-report-status="ready"' in body, body
    assert dom.count("<img") == 4 and "Sparse map" in dom
