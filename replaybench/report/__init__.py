"""The HTML report of a run folder, and the sample thumbnails it shows.

The report is built from the run folder alone (run.json, frames.csv, samples/), so it can be
rendered again later or on another machine.
"""

from __future__ import annotations

from replaybench.report.render import render_html, render_report
from replaybench.report.samples import sample_relpath, write_sample

__all__ = ['render_html', 'render_report', 'sample_relpath', 'write_sample']
