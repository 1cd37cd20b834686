"""replaybench's benchmark suite: ``python -m benchmarks [--quick] [--out PATH]``.

Every figure is a ratio against a baseline measured in the same run, on the same machine,
on data generated into a temporary folder; see docs/performance.md.
"""

__all__: list[str] = []
