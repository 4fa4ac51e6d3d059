"""The driving policy: its network (:mod:`~igdrivsim.policy.network`), acting and its own
episodes (:mod:`~igdrivsim.policy.act`), closed-loop rollouts
(:mod:`~igdrivsim.policy.closed_loop`)."""
