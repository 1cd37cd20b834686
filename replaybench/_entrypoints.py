"""What the registries of plugins (backends, tasks) share: the names a plugin may take and the
entry points of a group, read in a stable order."""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from importlib.metadata import EntryPoint

__all__ = ['PLUGIN_NAME', 'declares', 'sorted_entry_points']

#: A plugin's name: letters, digits, ``_`` and ``-``, not starting with ``_`` or ``-``.
PLUGIN_NAME = re.compile(r'[A-Za-z0-9][A-Za-z0-9_-]*\Z')

#: the import system's own finders: they find distributions only as ``declares`` looks for them
_PLAIN_FINDERS = frozenset({'BuiltinImporter', 'FrozenImporter', 'PathFinder'})


def declares(group: str) -> bool:
    """Whether an installed distribution may declare entry points of ``group``: a look at the
    ``entry_points.txt`` files of the distributions on ``sys.path``, so that
    ``importlib.metadata`` (with the email and zip modules it imports, some 20 ms) is loaded
    before a run's first frame only where one does. True wherever the look cannot be sure (a
    zip or other file on ``sys.path``, a finder of distributions besides the import system's);
    false only where ``importlib.metadata`` would find no entry point of ``group`` either."""
    import sys
    from pathlib import Path

    for finder in sys.meta_path:
        name = getattr(finder, '__name__', type(finder).__name__)
        if callable(getattr(finder, 'find_distributions', None)) and name not in _PLAIN_FINDERS:
            return True
    heading = f'[{group}]'
    for entry in sys.path:
        root = Path(entry or '.')
        try:
            children = [child.name for child in root.iterdir()]
        except NotADirectoryError:
            return True  # a zip file: importlib.metadata reads it
        except OSError:
            continue  # not there: nothing found in it
        folders = [root / 'EGG-INFO'] if root.name.lower().endswith('.egg') else []
        for child in children:
            low = child.lower()
            if low.endswith(('.dist-info', '.egg-info')):
                folders.append(root / child)
            elif low.endswith('.egg'):
                folders.append(root / child / 'EGG-INFO')
        for folder in folders:
            try:
                if heading in (folder / 'entry_points.txt').read_text(encoding='utf-8'):
                    return True
            except (FileNotFoundError, NotADirectoryError):
                continue
            except (OSError, UnicodeError):
                return True  # unreadable here: let importlib.metadata say
    return False


def sorted_entry_points(group: str) -> list[EntryPoint]:
    """The entry points of ``group``, in a stable order (name, then target)."""
    import importlib.metadata  # only plugins need it: not on a built-in's path

    eps = importlib.metadata.entry_points(group=group)
    return sorted(eps, key=lambda ep: (ep.name, ep.value))
