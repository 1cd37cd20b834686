"""The tracks task: a tracker's tracks over a box backend (``DETECTOR+TRACKER``,
``replaybench.backends.tracked``), their ids written into outputs.mcap and scored as
sequences against the ids of the box truth (HOTA, CLEAR, identity: ``replaybench.tracking``;
docs/tracking.md)."""

__all__: list[str] = []
