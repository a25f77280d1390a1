"""The vehicle segmenter network (PyTorch, training only; the product runs its ONNX export).

A small encoder-decoder over the 6-channel frame + background pair, built from depthwise-separable residual
blocks (about 0.2 GMAC at 480x272):

* encoder to 1/16 of the work size, dilated blocks at 1/16 for a receptive field of a near vehicle;
* decoder with additive skips to 1/8, 1/4 and 1/2;
* heads — ``mask``: vehicle logit per work pixel (1/2-resolution features, 2x2 sub-pixels by depth-to-space);
  ``centre``: instance-centre heatmap logit at 1/4; ``offset``: (dx, dy) from each 1/4 pixel to its instance's
  centre, in 1/4-resolution pixels (Panoptic-DeepLab style: pixels are grouped to the nearest predicted centre,
  so touching vehicles come out as separate instances).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


def conv_bn(cin: int, cout: int, k: int = 3, stride: int = 1, groups: int = 1, dilation: int = 1) -> nn.Sequential:
    pad = dilation * (k // 2)
    return nn.Sequential(nn.Conv2d(cin, cout, k, stride, pad, dilation=dilation, groups=groups, bias=False),
                         nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


class SepBlock(nn.Module):
    """Residual depthwise 3x3 + pointwise block."""

    def __init__(self, c: int, dilation: int = 1) -> None:
        super().__init__()
        self.dw = conv_bn(c, c, 3, groups=c, dilation=dilation)
        self.pw = nn.Sequential(nn.Conv2d(c, c, 1, bias=False), nn.BatchNorm2d(c))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(x + self.pw(self.dw(x)))


class Down(nn.Module):
    """Stride-2 depthwise 3x3 + pointwise channel change."""

    def __init__(self, cin: int, cout: int) -> None:
        super().__init__()
        self.dw = conv_bn(cin, cin, 3, stride=2, groups=cin)
        self.pw = conv_bn(cin, cout, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.pw(self.dw(x))


class Up(nn.Module):
    """1x1 to the skip's width, bilinear x2, add the skip, one block."""

    def __init__(self, cin: int, cout: int) -> None:
        super().__init__()
        self.reduce = conv_bn(cin, cout, 1)
        self.block = SepBlock(cout)

    def forward(self, x: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        x = F.interpolate(self.reduce(x), scale_factor=2.0, mode="bilinear", align_corners=False)
        return self.block(x + skip)


class VehicleSegNet(nn.Module):
    def __init__(self, width: tuple[int, int, int, int] = (16, 32, 64, 128)) -> None:
        super().__init__()
        c1, c2, c3, c4 = width
        self.stem = nn.Sequential(conv_bn(6, c1, 3, stride=2), SepBlock(c1))  # 1/2
        self.enc2 = nn.Sequential(conv_bn(c1, c2, 3, stride=2), SepBlock(c2), SepBlock(c2))  # 1/4
        self.enc3 = nn.Sequential(Down(c2, c3), SepBlock(c3), SepBlock(c3, 2), SepBlock(c3))  # 1/8
        self.enc4 = nn.Sequential(Down(c3, c4), SepBlock(c4), SepBlock(c4, 2), SepBlock(c4, 4),
                                  SepBlock(c4, 8))  # 1/16
        self.up3 = Up(c4, c3)
        self.up2 = Up(c3, c2)
        self.up1 = Up(c2, c1)
        self.centre = nn.Sequential(conv_bn(c2, c2, 3, groups=c2), nn.Conv2d(c2, 1, 1))
        self.offset = nn.Sequential(conv_bn(c2, c2, 3, groups=c2), nn.Conv2d(c2, 2, 1))
        self.mask = nn.Conv2d(c1, 4, 1)
        nn.init.constant_(self.centre[-1].bias, -4.0)  # rare positives (CenterNet's prior)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        s1 = self.stem(x)
        s2 = self.enc2(s1)
        s3 = self.enc3(s2)
        s4 = self.enc4(s3)
        d3 = self.up3(s4, s3)
        d2 = self.up2(d3, s2)
        d1 = self.up1(d2, s1)
        mask = F.pixel_shuffle(self.mask(d1), 2)
        return mask, self.centre(d2), self.offset(d2)
