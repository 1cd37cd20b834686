"""Applications: each wires sources, the replay engine and the sinks into one job.

``replaybench.app.sweep`` runs every (input, backend, parameter combination) of a sweep as an
ordinary run on Ray (docs/sweep.md). The submodules are imported by name; this package
re-exports nothing, so ``replaybench.app.sweep`` always names the module.
"""

from __future__ import annotations

__all__: list[str] = []
