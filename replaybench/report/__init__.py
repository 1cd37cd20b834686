"""The HTML report of a run folder, the sample thumbnails it shows, and the peak-rate page.

The report is built from the run folder alone (run.json, frames.csv, samples/), and peak.html
from peak.json alone, so both can be rendered again later or on another machine.
"""

from __future__ import annotations

from replaybench.report.peak import load_peak, render_peak_html, render_peak_report
from replaybench.report.render import render_html, render_report
from replaybench.report.samples import sample_relpath, write_sample
from replaybench.results.model import PEAK_SCHEMA_VERSION

__all__ = [
    'PEAK_SCHEMA_VERSION',
    'load_peak',
    'render_html',
    'render_peak_html',
    'render_peak_report',
    'render_report',
    'sample_relpath',
    'write_sample',
]
