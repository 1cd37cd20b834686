"""The stereo task's agreement type: two stereo backends' disparities against each other
(``replaybench.tasks.stereo.recording``)."""

from dataclasses import dataclass

__all__ = ['StereoAgreementRow']


@dataclass(frozen=True, slots=True)
class StereoAgreementRow:
    """Two stereo backends on one topic, over the pairs both returned a disparity for: the
    figures of ``backend_b``'s disparities taking ``backend_a``'s estimated pixels as truth
    (``replaybench.stereo.metrics``: EPE in pixels, bad-1/2/3 and density as shares)."""

    backend_a: str = ''
    backend_b: str = ''
    topic: str = ''
    frames: int = 0
    epe: float | None = None
    bad1: float | None = None
    bad2: float | None = None
    bad3: float | None = None
    density: float | None = None
