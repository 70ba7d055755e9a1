"""Shell completion of names and the machine-readable family list (issue 37 §2).

* `complete_experiments` — ``rtfit run``/``rtfit bench`` EXPERIMENT: the registry's names (`FAMILIES`), their
  aliases and ``all``;
* `complete_approx` — ``rtfit audit --approx A,B``: families and ``family:method`` ids, completing the last
  comma-separated item;
* `complete_scene` — ``rtfit audit SCENE``: the library's scene names, then files (the shell's own);
* `family_list` — ``rtfit list --json``: one record per family (name, title, audited, methods, quantities).

Click's completion is switched on per shell by its environment variable (bash:
``eval "$(_RTFIT_COMPLETE=bash_source rtfit)"``; zsh: ``zsh_source``; fish: ``fish_source``), README and
docs/audit.md. The callbacks read only the registry: no Mitsuba, no Dr.Jit, no scene is loaded.
"""

from __future__ import annotations

from click.shell_completion import CompletionItem

from rtfit.scenes import library_names

from .families import AUDITED, FAMILIES, METHOD_TABLES
from .registry import ALIASES

__all__ = ["complete_approx", "complete_experiments", "complete_scene", "family_list"]


def complete_experiments(_ctx, _param, incomplete: str) -> list[CompletionItem]:
    """Experiment names (and ``all``, the aliases) starting with ``incomplete``, with their titles."""
    named = [(n, f.title) for n, f in FAMILIES.items()]
    named += [(a, f"alias of {n}") for a, n in ALIASES.items()] + [("all", "every experiment")]
    return [CompletionItem(n, help=h) for n, h in named if n.startswith(incomplete)]


def complete_approx(_ctx, _param, incomplete: str) -> list[CompletionItem]:
    """``--approx`` items: the audited families and their ``family:method`` ids; the items before the last
    comma are kept as typed."""
    head, comma, last = incomplete.rpartition(",")
    prefix = head + comma
    names = [(n, f"family: {FAMILIES[n].title}" if n in FAMILIES else "family") for n in AUDITED]
    names += [(f"{n}:{mid}", m.label) for n in AUDITED for mid, m in METHOD_TABLES.get(n, {}).items()]
    return [CompletionItem(prefix + n, help=h) for n, h in names if n.startswith(last)]


def complete_scene(_ctx, _param, incomplete: str) -> list[CompletionItem]:
    """Library scene names starting with ``incomplete``, and the shell's own file completion."""
    names = [n for n in sorted(library_names()) if n.startswith(incomplete)]
    return [
        *(CompletionItem(n, help="library scene") for n in names),
        CompletionItem(incomplete, type="file"),
    ]


def family_list() -> list[dict]:
    """``rtfit list --json``: per family, ``name``, ``title``, ``audited`` (``rtfit audit`` runs it on a
    user's scene), ``methods`` (shipped method ids, registry order) and ``quantities`` (what they
    approximate: the audit's quantities for an audited family, else its methods' own)."""
    out = []
    for name, f in FAMILIES.items():
        methods = METHOD_TABLES.get(name) or (f.methods or {})
        audited = AUDITED.get(name)
        if audited is not None:
            quantities = [audited.quantity, *audited.quantities]
        else:
            quantities = [m.quantity for m in methods.values() if m.quantity]
        out.append(
            {
                "name": name,
                "title": f.title,
                "audited": audited is not None,
                "methods": list(methods),
                "quantities": list(dict.fromkeys(q for q in quantities if q)),
            }
        )
    return out
