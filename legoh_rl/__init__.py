"""legoh-rl: the LEGO-H humanoid hiking system as a TorchRL pipeline.

Subpackages:
    envs        batched MuJoCo hiking environment (robots, physics, trails, sensors, rewards)
    transforms  TensorDict transforms (depth history, goal tiling, perception hold)
    modules     TensorDictModules (TC-ViT, locomotion policy, oracle actor-critic, masked VAE)
    objectives  LossModules (PPO builder, DAgger, masked-VAE reconstruction, HLM)
"""

__version__ = "0.1.0"
