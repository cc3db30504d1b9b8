"""Names of vector signals, shared by the FMU slaves and the scenarios."""


def indexed(base: str, count: int) -> list[str]:
    """``[base]`` for one channel, ``[base1, ..., baseN]`` otherwise."""
    return [base] if count == 1 else [f"{base}{i + 1}" for i in range(count)]
