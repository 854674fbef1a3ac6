"""Imitation of the ORCA robot for SB3's and sb3-contrib's algorithms (PPO, A2C, MaskablePPO, DQN, QR-DQN).

``APGValue`` starts from 3,000 episodes of the ORCA robot (paper §3); the SB3 baselines get the
same start here, so that Table 3 compares learners, not exploration luck: with a success-only
reward, 80 actions and no lookahead, PPO and DQN from scratch rarely reach the goal at all.

- :func:`collect_demonstrations` runs :class:`~sb3_crowdnav.sim.orca.OrcaPolicy` (the
  ``"constrained"`` mapping, as ``APGValue``'s demonstrator) in a VecEnv and keeps every transition.
- :func:`pretrain_actor_critic` (PPO, A2C, MaskablePPO): behaviour cloning, maximising the log-probability of the
  demonstrator's action, plus regression of the critic on the discounted returns.
- :func:`pretrain_dqn` (DQN, QR-DQN): the demonstrations go into the replay buffer and the Q-network takes
  gradient steps on them: 1-step Q-learning with the target network plus DQfD's large-margin loss
  ``max_a [Q(s, a) + m·1(a ≠ a_E)] - Q(s, a_E)`` (Hester et al. 2018), which keeps actions never
  demonstrated below the demonstrated one (QR-DQN: quantile regression as the TD part, the margin on the mean over
  the quantiles). The demonstrations stay in the replay buffer with their episode ends
  (:func:`add_to_replay_buffer`), so that n-step targets stop there.
- :class:`DQfD`: a DQN that keeps taking gradient steps on the demonstrations during RL.
"""

from sb3_crowdnav.imitation.demonstrations import Demonstrations, collect_demonstrations
from sb3_crowdnav.imitation.dqfd import DQfD
from sb3_crowdnav.imitation.pretrain import add_to_replay_buffer, pretrain_actor_critic, pretrain_dqn, pretrain_value

__all__ = ["DQfD", "Demonstrations", "add_to_replay_buffer", "collect_demonstrations", "pretrain_actor_critic",
           "pretrain_dqn", "pretrain_value"]
