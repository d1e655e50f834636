"""Reference poses from a second log (a corrected log, or one with TRUEPOS), joined by timestamp."""

from __future__ import annotations

import dataclasses

import numpy as np

from vgm_studio.datasets.scans import ScanLog
from vgm_studio.errors import InputError


def with_reference(log: ScanLog, reference: ScanLog, tolerance: float = 0.05) -> ScanLog:
    """Returns ``log`` whose scans carry the reference pose of the nearest-in-time reference scan.

    Scans with no reference scan within ``tolerance`` seconds get none.

    Raises:
        InputError: The reference log has no reference poses, or no timestamp matches.
    """
    ref_poses = reference.reference_poses()
    if ref_poses is None:
        raise InputError(
            reference.path,
            "has no reference poses (not a corrected log and no "
            "TRUEPOS); use --poses reference if its scan poses are corrected",
        )
    ref_t = reference.timestamps
    order = np.argsort(ref_t)
    ref_t, ref_poses = ref_t[order], ref_poses[order]
    scans, matched = [], 0
    for scan in log.scans:
        k = int(np.searchsorted(ref_t, scan.timestamp))
        cands = [j for j in (k - 1, k) if 0 <= j < len(ref_t)]
        best = min(cands, key=lambda j: abs(ref_t[j] - scan.timestamp))
        pose = ref_poses[best] if abs(ref_t[best] - scan.timestamp) <= tolerance else None
        matched += pose is not None
        scans.append(dataclasses.replace(scan, reference=pose))
    if matched == 0:
        raise InputError(
            reference.path,
            f"no scan timestamp matches {log.path} within "
            f"{tolerance} s (do both logs use the same clock?)",
        )
    return dataclasses.replace(log, scans=scans, reference_origin=str(reference.path))
