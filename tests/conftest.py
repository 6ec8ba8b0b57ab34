import os
import warnings

os.environ.setdefault("MUJOCO_GL", "disable")
warnings.filterwarnings("ignore", message=".*is different from the unwrapped version.*")
