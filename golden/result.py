"""The outcome of detecting one frame, shared by both golden models and the co-simulation."""

from dataclasses import dataclass, field

from lodestar import contract as C


@dataclass
class DetectionResult:
    """Records and frame header of one frame.

    ``blobs`` are ``contract.BlobRecord`` in emission order (raster order of each blob's last
    pixel).  ``threshold``/``background`` are T and B in effect (see ``contract.HEADER_FIELDS``
    for local mode).  Counts follow the contract: ``n_blobs`` tracked blobs completed,
    ``n_filtered`` rejected by the filters, ``dropped_records`` lost to a full record buffer,
    ``dropped_labels`` untracked blobs lost to label overflow.
    """

    blobs: list
    mode: int
    threshold: int
    background: int
    n_blobs: int
    n_filtered: int
    dropped_records: int
    dropped_labels: int
    flags: int
    frame_counter: int = 0
    width: int = field(default=0, compare=False)
    height: int = field(default=0, compare=False)
    pixel_bits: int = field(default=0, compare=False)

    @property
    def dropped(self):
        """Blobs lost to capacity limits: ``dropped_records + dropped_labels``."""
        return self.dropped_records + self.dropped_labels

    @property
    def mode_name(self):
        return C.MODE_NAMES[self.mode]

    def header(self):
        """Header fields by name as ``contract.HEADER_FIELDS`` orders them (no magic/version)."""
        return {
            "mode": self.mode,
            "frame_counter": self.frame_counter,
            "width": self.width,
            "height": self.height,
            "pixel_bits": self.pixel_bits,
            "flags": self.flags,
            "threshold": self.threshold,
            "background": self.background,
            "n_blobs": self.n_blobs,
            "n_filtered": self.n_filtered,
            "dropped_records": self.dropped_records,
            "dropped_labels": self.dropped_labels,
            "n_records": len(self.blobs),
        }
