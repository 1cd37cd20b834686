"""report.html's agreement between backends, from run.json ``agreement``."""

from __future__ import annotations

from typing import TYPE_CHECKING

from replaybench.report.formats import fmt, fmt_frac, fmt_value, swatch
from replaybench.report.markup import escaped

if TYPE_CHECKING:
    from collections.abc import Mapping

    from replaybench.results.model import AgreementRow, RunResult

__all__ = ['agreement_html']


def _frame_name(key: tuple[int, int], single_input: bool) -> str:
    index, seq = key
    return f'#{seq}' if single_input else f'{index}:#{seq}'


def agreement_html(run: RunResult, colours: Mapping[str, str]) -> str:
    """Agreement between backends per topic, from run.json ``agreement``."""
    if not run.agreement:
        return ''
    single_input = len(run.inputs) <= 1
    threshold = run.settings.agreement_iou
    by_topic: dict[str, list[AgreementRow]] = {}
    for entry in run.agreement:
        by_topic.setdefault(entry.topic or '?', []).append(entry)
    head = (
        '<tr><th>backends (a / b)</th><th class="n">frames</th><th class="n">detections a</th>'
        '<th class="n">detections b</th><th class="n">matched</th><th class="n">of a</th>'
        '<th class="n">of b</th><th class="n">mean IoU</th><th class="n">mean |Δscore|</th>'
        '<th>most disagreeing frames</th></tr>'
    )
    intro = (
        f'Per frame both backends processed, detections of the same class are paired greedily '
        f'by IoU ≥ {threshold:g} (highest first). "of a" / "of b": share of each backend\'s '
        'detections that found a partner. No ground truth is involved. Most disagreeing frames '
        'first (most unmatched detections), as #seq of the topic.'
    )
    parts = [
        f'<h2 id="agreement">Agreement between backends</h2><p class="muted">{escaped(intro)}</p>'
    ]
    for topic, rows in by_topic.items():
        body = []
        for entry in rows:
            a, b = entry.backend_a or '?', entry.backend_b or '?'
            frames = [_frame_name(k, single_input) for k in entry.disagreeing_frames]
            shown = ', '.join(frames[:6]) + (f' … (+{len(frames) - 6})' if len(frames) > 6 else '')
            body.append(
                f'<tr><td>{swatch(colours, a)}{escaped(a)} / {swatch(colours, b)}{escaped(b)}</td>'
                f'<td class="n">{escaped(fmt_value(entry.frames))}</td>'
                f'<td class="n">{escaped(fmt_value(entry.n_a))}</td>'
                f'<td class="n">{escaped(fmt_value(entry.n_b))}</td>'
                f'<td class="n">{escaped(fmt_value(entry.matched))}</td>'
                f'<td class="n">{escaped(fmt_frac(entry.matched_frac_a))}</td>'
                f'<td class="n">{escaped(fmt_frac(entry.matched_frac_b))}</td>'
                f'<td class="n">{escaped(fmt(entry.mean_iou, 3))}</td>'
                f'<td class="n">{escaped(fmt(entry.mean_abs_score_diff, 3))}</td>'
                f'<td title="{escaped(", ".join(frames))}">'
                f'{escaped(shown) if frames else "none"}</td></tr>',
            )
        parts.append(
            f'<h3><code>{escaped(topic)}</code></h3><div class="table-wrap"><table>'
            f'<thead>{head}</thead><tbody>{"".join(body)}</tbody></table></div>',
        )
    return ''.join(parts)
