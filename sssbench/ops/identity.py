"""TEMPORARY stand-in (replaced by the decision branch's IdentitySSS)."""

import torch
from torch import nn


class IdentitySSS(nn.Module):
    needs: tuple[str, ...] = ()

    def __init__(self) -> None:
        super().__init__()

    def forward(self, gbuffer, **kwargs) -> torch.Tensor:
        return gbuffer.diffuse.clone()
