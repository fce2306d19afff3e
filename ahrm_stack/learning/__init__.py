"""Learning: the reward mechanisms (AHRM, MHRM, FHRM, LS), PPO, the trainer, collection, run folders.

Which code path is production, and what holds it (one list, kept here):

=========================  ==========================================  ===============================
job                        production                                  held to (in the tests)
=========================  ==========================================  ===============================
collection                 :class:`~.collection.LeanCollector`, with    TorchRL's ``Collector`` over a
                           :class:`~.ppo.LeanCollectionActor`; worker   ``ParallelEnv`` of the same
                           processes as :class:`~.pool.EnvPool`         workers
                                                                        (``tests/torchrl_reference.py``)
PPO loss                   :class:`~.lean_loss.LeanClipPPOLoss` where   TorchRL's ``ClipPPOLoss``
                           :func:`~.lean_loss.lean_loss_for` applies    (``tests/test_lean_loss.py``)
                           (no entropy bonus); TorchRL's
                           ``ClipPPOLoss`` otherwise (``profile=paper``
                           trains with an entropy bonus, whose TanhNormal
                           estimate draws samples)
evaluation (sim)           :class:`~.ppo.LeanActor` (torch; what         the TorchRL actor under
                           :func:`~.rollouts.load_policy` returns)       ``ExplorationType.DETERMINISTIC``
deploy (every tick)        :class:`~ahrm_stack.deploy.policy.           ``LeanActor.act`` to 1e-5
                           NumpyPolicy` (NumPy, preallocated)           (``tests/test_deploy_fast.py``)
=========================  ==========================================  ===============================

Evaluation and deploy keep two forward passes on purpose: ``NumpyPolicy`` allocates nothing per
tick (the deploy loop's budget), ``LeanActor`` runs inside TorchRL's rollouts. They differ by float32
rounding only (≤ 5e-7 on the default policy; BLAS summation order), and moving evaluation onto
``NumpyPolicy`` would change the last digits of every committed evaluation, so evaluation stays on torch.
"""
