"""A YAML parse error in one line, for the messages that refuse a file.

PyYAML's own text spans several lines with a caret drawing; a refused option should
say where and what in one line (docs/running.md, "Bad input").
"""
from __future__ import annotations


def yaml_problem(error: Exception) -> str:
    """``'line N: what'`` of a ``yaml.YAMLError`` (or the error's class name when PyYAML
    gives no position), never more than one line."""
    mark = getattr(error, 'problem_mark', None)
    problem = getattr(error, 'problem', None) or ' '.join(str(error).split()) or type(error).__name__
    return f'line {mark.line + 1}: {problem}' if mark is not None else str(problem)
