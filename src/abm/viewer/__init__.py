"""See what the policy sees: a local 3-D web viewer (``abm view``) of episodes and rollouts.

:mod:`abm.viewer.record` turns an episode, a policy's explanations or a rollout into plain arrays;
:mod:`abm.viewer.server` draws them with viser; :mod:`abm.viewer.browser` takes headless-Chromium
screenshots of the page (docs, browser tests).
"""

from typing import TYPE_CHECKING

from abm.lazy import lazy_exports

if TYPE_CHECKING:  # the exports; at run time each is imported on first use (abm.lazy), so importing the
    # package (every `abm` command does) stays light
    from abm.grounding.visualize import overlay_views
    from abm.viewer.record import (
        ViewerRecord,
        ViewerStep,
        record_from_episode,
        record_rollout,
        view_camera_pose,
    )

__getattr__, __dir__ = lazy_exports(__name__, __file__)

__all__ = ["ViewerRecord", "ViewerStep", "overlay_views", "record_rollout", "record_from_episode", "view_camera_pose"]
