"""Building blocks of the relighting diffusion model (SPEC section 4): gated MD/HA
convolutions, ControlNet-shaped branches, attention-based feature selection, the
condition encoder (background consistency encoder + translated specular prior), light/view
tokens and the decoupled (IP-Adapter style) cross-attention."""

from relight.modules.afs import AttentionFeatureSelection
from relight.modules.branches import Branch
from relight.modules.condition import ConditionEncoder, shuffle_within_groups
from relight.modules.gated import HAConv, InceptionPath, MDConv, PlainConv
from relight.modules.ip_attention import DecoupledAttnProcessor, install_decoupled_attention
from relight.modules.light_tokens import LightTokenEncoder

__all__ = [
    "MDConv",
    "HAConv",
    "PlainConv",
    "InceptionPath",
    "Branch",
    "AttentionFeatureSelection",
    "ConditionEncoder",
    "shuffle_within_groups",
    "LightTokenEncoder",
    "DecoupledAttnProcessor",
    "install_decoupled_attention",
]
