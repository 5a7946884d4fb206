"""A wrong joint convention caught in a session: the robot settles, again and again, where no plan
target is, and a flipped sign (or a joint's zero off by a constant) in the robot file's
``[controller]`` would put those settles on targets (``calib.conventions.convention_mistake``).
Said once in the log, with the fix, and again in the session's timeout ending."""

from __future__ import annotations

import numpy as np

from calib.conventions import convention_mistake

AWAY_SETTLES = 3  # distinct settles away from every target before the finder is asked
KEPT = 20  # distinct settles kept, at most (the finder's cost grows with them)


class AwaySettles:
    """Settles that matched no target of a plan (``targets_deg`` (M, 6) [deg], ``target_ids``
    (M,)) within ``match_deg`` [deg], read under the robot file's ``controller`` (its
    ``[controller]``, from ``where``). ``advice``: the mistake found and its fix, once found."""

    def __init__(self, targets_deg, target_ids, match_deg: float, controller, where: str):
        self.targets, self.ids = np.asarray(targets_deg, float), np.asarray(target_ids, int)
        self.match_deg, self.controller, self.where = match_deg, controller, where
        self.settles: list[np.ndarray] = []
        self.advice: str | None = None

    def settled(self, q_deg) -> str | None:
        """The robot settled at ``q_deg`` (6,) [deg], at no target: the advice when first found."""
        q = np.asarray(q_deg, float)
        known = any(np.max(np.abs(q - s)) <= self.match_deg for s in self.settles)
        if self.advice is not None or known or len(self.settles) >= KEPT:
            return None
        self.settles.append(q)
        if len(self.settles) < AWAY_SETTLES:
            return None
        sign, offset = self.controller.joint_sign, self.controller.joint_offset_deg
        found = convention_mistake(np.array(self.settles), self.targets, self.match_deg, sign, offset)
        if found is not None:
            self.advice = self._advice(found)
        return self.advice

    def _advice(self, found) -> str:
        at = found.targets >= 0
        targets = ", ".join(str(t) for t in sorted({int(self.ids[k]) for k in found.targets[at]}))
        if found.shifted is not None:
            joint, deg = found.shifted
            how = f"with joint {joint + 1}'s zero moved by {deg:g} deg"
            key = f"joint_offset_deg = {_numbers(found.joint_offset_deg)}"
        else:
            names = [f"{j + 1}'s" for j in found.flipped]
            joints = names[0] if len(names) == 1 else ", ".join(names[:-1]) + f" and {names[-1]}"
            how = f"with joint {joints} sign{'s' if len(names) > 1 else ''} flipped"
            key = f"joint_sign = {_numbers(found.joint_sign)}"
        untold = ""
        if found.untold:
            joints = ", ".join(str(j + 1) for j in found.untold)
            untold = (
                f" (these settles do not tell joint {joints}'s sign: check it against the controller's axes)"
            )
        return (
            f"the robot settled {len(self.settles)} times away from every target; {how}, {int(at.sum())} of "
            f"them lie at targets {targets}: set [controller] {key} in {self.where}{untold}"
        )


def _numbers(values) -> str:
    """``[-1, 1, ...]``: each value as TOML writes it, integers without a point."""
    return "[" + ", ".join(f"{float(v):g}" for v in values) + "]"
