"""`rig study`: a protocol run on the simulated rig over many seeds, scored against the world's truth.

Layer: between `rig.cli` and `rig.rigs` (it composes simulated rigs through `rig.rigs`).
"""
