"""The closed GNC loop: Basilisk dynamics, frames, guidance and control, and the pure
closed-loop step (docs/loop.md). Needs the optional extra ``[loop]`` (Basilisk) for
``dynamics``; the other modules are numpy only."""
