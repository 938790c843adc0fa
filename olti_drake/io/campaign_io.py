"""Reading SCARA campaign files for identification: one reading d_j(k) of Eq. (10) of 000 per row, columns :data:`REQUIRED`.

Units: mm and degrees. Rows with ``valid`` = 0 are kept in the file and
skipped here; every error names the file, the line and the column.
"""

import os
from dataclasses import dataclass

import numpy as np

from olti_drake.io.csvio import (InputError, check_finite, check_indices, check_no_duplicate_rows, check_values, data_digest,
                    read_table)
from olti_drake.model.scara import JointCommands

REQUIRED = ("reflector", "theta1_deg", "theta2_deg", "dir1", "dir2", "displacement_mm")
OPTIONAL = ("theta4_deg", "valid")


@dataclass(frozen=True)
class CampaignData:
    """The valid readings of a campaign: reflector index j, commands, d_j(k) (mm), file lines."""

    reflector: np.ndarray
    commands: JointCommands
    displacement_mm: np.ndarray
    line: np.ndarray
    source: str = ""
    n_skipped: int = 0

    def __len__(self) -> int:
        return self.reflector.size

    @property
    def n_reflectors(self) -> int:
        return int(self.reflector.max()) + 1

    def subset(self, rows) -> "CampaignData":
        """The readings at ``rows`` (a boolean mask or indices)."""
        c = self.commands
        return CampaignData(self.reflector[rows], JointCommands(c.theta1_deg[rows], c.theta2_deg[rows],
                                                                c.dir1[rows], c.dir2[rows]),
                            self.displacement_mm[rows], self.line[rows], self.source, self.n_skipped)


def load_campaign(path) -> CampaignData:
    """Load a SCARA campaign CSV; skip ``valid`` = 0 rows; validate what is used.

    Checks (one-line errors): required columns, numbers, finite values in the
    valid rows, directions ±1, reflector indices whole numbers 0..N_t-1 with
    every index used.
    """
    name = os.fspath(path)
    t = read_table(path, REQUIRED, OPTIONAL, integer=("reflector", "dir1", "dir2", "valid"))
    if "valid" in t:
        check_values(t, path, "valid", (0.0, 1.0))
    keep = t["valid"] == 1 if "valid" in t else np.ones(t["_line"].size, dtype=bool)
    if not keep.any():
        raise InputError(f"{name}: no valid readings (every row has valid = 0)")
    t = {k: v[keep] for k, v in t.items()}
    check_no_duplicate_rows(t, path)
    check_finite(t, path, REQUIRED)
    for c in ("dir1", "dir2"):
        check_values(t, path, c, (-1.0, 1.0))
    j = check_indices(t, path, "reflector")
    return CampaignData(j, JointCommands(t["theta1_deg"], t["theta2_deg"], t["dir1"], t["dir2"]),
                        t["displacement_mm"], t["_line"], name, int((~keep).sum()))


def campaign_digest(data) -> dict:
    """{"readings", "sha256"} of the valid readings a result was identified from (SCARA, machine or N-joint
    campaign: the last digests itself, ``SerialCampaign.digest``)."""
    if hasattr(data, "digest"):
        return data.digest()
    if hasattr(data, "commands_mm"):  # MachineCampaign; 3D: z command and tool too (2D digests unchanged)
        cmd = data.commands_mm[data.target]
        more = () if cmd.shape[1] == 2 else (cmd[:, 2], data.tool[data.target])
        return data_digest(data.station, data.target, cmd[:, 0], cmd[:, 1], *more, data.displacement_mm)
    c = data.commands
    return data_digest(data.reflector, c.theta1_deg, c.theta2_deg, c.dir1, c.dir2, data.displacement_mm)


def check_campaign_matches(result: dict, data, result_path) -> str:
    """Refuse a campaign that is not the one the result was identified from (count and digest, naming both);
    return a note ('' when matched) -- results written before the digest existed are accepted with a note."""
    stored = result.get("campaign")
    here = campaign_digest(data)
    if not isinstance(stored, dict) or "sha256" not in stored:
        return (f"{os.fspath(result_path)} carries no campaign digest (written by an older version): not checked "
                f"that {data.source} is its campaign")
    if stored.get("sha256") != here["sha256"] or stored.get("readings") != here["readings"]:
        raise InputError(f"{data.source}: not the campaign {os.fspath(result_path)} was identified from: "
                         f"{here['readings']} valid readings, sha256 {here['sha256'][:12]}..., but the result's "
                         f"campaign has {stored.get('readings')} readings, sha256 {str(stored.get('sha256'))[:12]}...")
    return ""


def load_commands(path):
    """Load a ``commands.csv`` (θ1*, θ2* deg; dir1, dir2 ±1), formats.md -> (JointCommands, file lines)."""
    cols = ("theta1_deg", "theta2_deg", "dir1", "dir2")
    t = read_table(path, cols, integer=("dir1", "dir2"))
    check_finite(t, path, cols)
    for c in ("dir1", "dir2"):
        check_values(t, path, c, (-1.0, 1.0))
    return JointCommands(*(t[c] for c in cols)), t["_line"]
