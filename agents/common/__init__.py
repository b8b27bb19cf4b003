"""What the trainers share, and what uses a trained policy.

- `config`: the trainers' configs (`PPOConfig`, `APGConfig`), loaded strictly
  from YAML;
- `networks`: the shared actor-critic and its action distribution;
- `batch`: B roundabouts stepped side by side and the AVs' bookkeeping
  (`BatchTrainer`, the base of every trainer);
- `losses`: what the losses share (`masked_mean`);
- `export`: the trained policy as ``policy.npz`` + ``policy.json``;
- `evaluation`: an exported policy in JAX, across penetrations and seeds;
- `behaviour`: what the policy does differently from an uncontrolled AV;
- `compilation`: the persistent cache of compiled programs.
"""
