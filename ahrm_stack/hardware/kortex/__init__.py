"""The Kortex backend: a Kinova Gen3-family arm over the vendor's ``kortex_api`` (docs/kortex.md).

``kortex_api`` is not on PyPI; it is an optional extra (see :data:`INSTALL_HINT`). Kortex drives
the Gen3 family (Gen3, Gen3 lite), not the JACO Gen2 the default task models.

Modules, one idea each:

* :mod:`~ahrm_stack.hardware.kortex.vendor_link` — the only code that calls ``kortex_api`` (standard library
  otherwise), in plain values; it runs in a child process of its own.
* :mod:`~ahrm_stack.hardware.kortex.child_link` — that child process, over a pipe (JSON lines).
* :mod:`~ahrm_stack.hardware.kortex.arm` — :class:`KortexArm`, the adapter.
* :mod:`~ahrm_stack.hardware.kortex.freshness` — feedback stamps and frozen-frame detection.
* :mod:`~ahrm_stack.hardware.kortex.arm_model` — the arm's model, DoF, speed hard limits and kinematic soft
  limits against the policy's.
* :mod:`~ahrm_stack.hardware.kortex.moves` — the ``--home`` move: one ReachJointAngles action and its
  notifications, read without waiting.
* :mod:`~ahrm_stack.hardware.kortex.home` — ``--home``: :class:`~ahrm_stack.hardware.kortex.home.KortexHoming`.
* :mod:`~ahrm_stack.hardware.kortex.check` — ``--check``: a run's per-tick RPCs against the send deadline.
* :mod:`~ahrm_stack.hardware.kortex.zones` — protection zones, reported and checked against the workspace.
* :mod:`~ahrm_stack.hardware.kortex.watchdog`, :mod:`~ahrm_stack.hardware.kortex.codec`,
  :mod:`~ahrm_stack.hardware.kortex.credentials`, :mod:`~ahrm_stack.hardware.kortex.settings`,
  :mod:`~ahrm_stack.hardware.kortex.backend` (deploy wiring).

Safety of the link, each number from ``configs/deploy.yaml``'s ``kortex`` section
(:func:`kortex_options`):

* **Its own process.** ``kortex_api`` 2.6.0 pins ``protobuf`` 3.x (3.20 on Python >= 3.10), which
  breaks tensorboard and ray here; it runs in a child process under ``kortex.python`` (a virtual
  environment of its own; default this interpreter) and talks plain values over a pipe. This
  process never imports ``kortex_api`` or ``protobuf``. When the adapter's process dies, the
  child sees its input end and sends ``Base.Stop`` before it exits.
* **Explicit timeouts.** Every RPC carries its own ``RouterClientSendOptions.timeout_ms``
  (``rpc_timeout_ms`` for feedback and motion, ``session_rpc_timeout_ms`` for the login and the
  reads on connect), never the vendor's 10 s default; the child must answer within that plus
  ``process_margin_ms`` or it is killed.
* **Lost link: Stop, then disconnect.** A connection error (``KClientException``, a dropped
  session) sends ``Base.Stop`` (best effort, ``lost_link_stop_timeout_ms``), closes the session,
  ends the child and records why (:attr:`KortexArm.lost_reason`, the log); the call raises
  :class:`~ahrm_stack.hardware.protocol.ConnectionLostError`. A dead or hung child is a lost link too, but
  then no Stop can be sent: the arm's own ``connection_inactivity_timeout_ms`` (2 s) is the only
  guard.
* **Command watchdog.** Joint-speed commands never expire on the arm; :class:`CommandWatchdog`
  sends ``Base.Stop`` when no fresh command came for ``watchdog_periods`` control periods while
  the arm was commanded to move, and latches until :meth:`KortexArm.clear_faults` (the
  protocol's rule, :class:`~ahrm_stack.hardware.protocol.ArmAdapter`): feedback and the command gate report
  it as ``Fault.WATCHDOG``.
* **Staleness without an arm clock.** ``Feedback.frame_id`` is client-set (it echoes the last
  cyclic command's), and feedback has no timestamp: frames are stamped on the adapter's clock
  when requested, and a frame identical in every analogue reading to the previous one is a
  repeat (:mod:`~ahrm_stack.hardware.kortex.freshness`).
* **The arm model checked.** On connect the arm's ``ProductConfiguration`` model and DoF must be
  the ones ``kortex.models`` gives for the policy's robot description, and its joint speed hard
  limits and its ``ControlConfig`` soft limits (the lowest over ``kortex.soft_limit_modes``) must
  allow the description's velocity limits (:mod:`~ahrm_stack.hardware.kortex.arm_model`).
* **Protection zones** are read on connect, logged (:attr:`KortexArm.zone_summary`), and refused
  when one reaches into the task workspace (``kortex.refuse_zones_in_workspace``).
* **Faults.** Motion commands raise :class:`~ahrm_stack.hardware.protocol.ArmFaultError` while the arm reports
  a fault, after an e-stop, after a watchdog stop, or when the arm refuses them as in fault;
  :meth:`KortexArm.clear_faults` runs ros2_kortex's reset sequence.

Credentials come from environment variables or a file outside the repository, never logged,
never in an error message (:func:`scrub`). The robot address is always explicit: there is no
default address, and nothing is contacted before :meth:`KortexArm.connect`.
"""

from ahrm_stack.hardware.kortex.arm import KortexArm, KortexNotInstalledError
from ahrm_stack.hardware.kortex.arm_model import describe_arm, model_name, model_refusal, soft_limit_refusal
from ahrm_stack.hardware.kortex.backend import (import_kortex_api, kortex_bring_up_blocker,
                                                kortex_deploy_blocker, make_kortex_backend)
from ahrm_stack.hardware.kortex.child_link import ChildLink
from ahrm_stack.hardware.kortex.codec import (arm_state_from_kortex, degrees_to_radians, faults_from_banks,
                                   feedback_from_values, joint_speeds_message, radians_to_degrees,
                                   servoing_mode_name, unwrap_positions)
from ahrm_stack.hardware.kortex.credentials import (CREDENTIALS_FILE_ENV, PASSWORD_ENV, REPOSITORY_ROOT,
                                         USERNAME_ENV, Credentials, CredentialsError,
                                         load_credentials, scrub, secret_variants)
from ahrm_stack.hardware.kortex.freshness import FrameFreshness, fingerprint
from ahrm_stack.hardware.kortex.settings import KortexModel, KortexOptions, kortex_options
from ahrm_stack.hardware.kortex.vendor_link import INSTALL_HINT, KORTEX_MODULES, LinkError, VendorLink
from ahrm_stack.hardware.kortex.watchdog import CommandWatchdog
from ahrm_stack.hardware.kortex.zones import ProtectionZone, task_workspace, zone_report, zones_in_workspace

__all__ = [
    "CREDENTIALS_FILE_ENV", "ChildLink", "CommandWatchdog", "Credentials", "CredentialsError",
    "FrameFreshness", "INSTALL_HINT", "KORTEX_MODULES", "KortexArm", "KortexModel",
    "KortexNotInstalledError", "KortexOptions", "LinkError", "PASSWORD_ENV", "ProtectionZone",
    "REPOSITORY_ROOT", "USERNAME_ENV", "VendorLink", "arm_state_from_kortex", "degrees_to_radians",
    "describe_arm", "faults_from_banks", "feedback_from_values", "fingerprint",
    "import_kortex_api", "joint_speeds_message", "kortex_bring_up_blocker", "kortex_deploy_blocker",
    "kortex_options", "soft_limit_refusal",
    "load_credentials", "make_kortex_backend", "model_name", "model_refusal", "radians_to_degrees",
    "scrub", "secret_variants", "servoing_mode_name", "task_workspace", "zone_report",
    "unwrap_positions", "zones_in_workspace",
]
