"""``delaycomp list``: the scenarios and their parameters, from the shipped loop files as
TOML holds them (no numpy)."""

from __future__ import annotations

from delaycomp.paper import scenarios  # light: no numpy until a loop is read

#: width of ``delaycomp list`` (it fits a 100-column terminal)
LIST_WIDTH = 100


def cmd_list(args) -> int:
    """``delaycomp list``: each scenario with its title and stop time, and its parameters
    (default, meaning, allowed values), wrapped to ``LIST_WIDTH`` columns."""
    import textwrap

    indent = " " * 30
    for number, sc in enumerate(scenarios.SCENARIOS.values()):
        if number:
            print()
        shown = sc.listing()  # the shipped files as TOML holds them: no numpy
        print(textwrap.fill(f"{sc.name}: {shown.title} (stop time {shown.stop_time:g} s)",
                            LIST_WIDTH, subsequent_indent="  "))
        print(f"    {'NAME':<9} {'DEFAULT':<15} MEANING; ALLOWED VALUES")
        for p in shown.params:
            if isinstance(p.default, tuple):
                default = ",".join(f"{v:g}" for v in p.default)
            elif p.default is None:  # derived from other parameters
                default = {"r_true": "(= r)", "tau_true": "(= tau)"}.get(p.name,
                                                                        "(depends on n)")
            elif isinstance(p.default, float):
                default = f"{p.default:g}"
            else:
                default = str(p.default)
            head = f"    {p.name:<9} {default:<15} "
            if len(head) > len(indent):  # a long default: the text on the next line
                print(head.rstrip())
                head = indent
            # an equation ("h = T/N", "u = -k x") stays on one line: its spaces are held by
            # a placeholder while the text is wrapped
            text = f"{p.help}; {p.allowed}".replace(" = ", "\0=\0")
            print(textwrap.fill(text, LIST_WIDTH, initial_indent=head,
                                subsequent_indent=indent,
                                break_on_hyphens=False).replace("\0", " "))
    return 0
