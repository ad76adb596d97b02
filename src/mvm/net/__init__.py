"""The monocular multi-person 3D pose network (Section 5 of the paper).

One module per stage, as in the bottom-up pose networks it follows:

- ``headmeta``: small frozen dataclasses, the contract between heads, encoders and decoders;
- ``backbone``: ResNet with torchvision's parameter names;
- ``heads`` and ``model``: the PIF, PAF and PDF heads on top of the backbone;
- ``encoder``: annotations -> field targets;  ``decoder``: fields -> poses with depth;
- ``losses``: L = λ1·L_PIF + λ2·L_PAF + λ3·L_PDF;  ``scale``: the length-scale calibration s*;
- ``data``, ``train``, ``predict``, ``render`` (synthetic people), ``metrics``.

Everything here needs ``torch`` (the ``net`` extra) except ``headmeta``, ``encoder``,
``decoder``, ``scale``, ``render`` and ``metrics``, which are plain numpy.
"""
