"""Static shapes for compiled functions: the one padding rule for frame counts."""


def padded_length(n: int) -> int:
    """Frames a sequence of ``n`` is padded to: 16, then four sizes per doubling (20, 24, 28,
    32, 40, ...). Padded frames cost as much as real ones, so the step bounds the waste at a
    quarter of the real frames (a 17-frame clip costs 20, not 32); each size compiles a jitted
    function once per process, so clips of many lengths share a few compilations (online
    inference over growing prefixes compiles about four times per doubling)."""
    if n <= 16:
        return 16
    step = 1 << max((n - 1).bit_length() - 3, 0)  # a quarter of the doubling n falls in
    return -(-n // step) * step
