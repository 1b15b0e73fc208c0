"""Exceptions that carry a message meant for the user, not a traceback."""


class SkinTopoError(ValueError):
    """An error caused by the input or the options (a file, a folder, a value given by the
    user), with a message that says what is wrong. A ``ValueError``, so callers that catch
    bad values catch it too.

    The command-line interface prints the message of these errors without a traceback.
    A library function called against its contract (arrays of the wrong shape or kind, which
    no input file can cause once it has been validated) raises a plain ``ValueError`` or
    ``TypeError`` instead: that is a bug in the caller, and its traceback is wanted.
    """


class AcquisitionError(SkinTopoError):
    """An acquisition folder or manifest that fails validation.

    Parameters
    ----------
    source : str
        The folder or manifest that was read.
    problems : list of str
        Every problem found, each naming the file and the field concerned.
    """

    def __init__(self, source, problems):
        self.source = str(source)
        self.problems = list(problems)
        lines = "\n".join(f"  - {p}" for p in self.problems)
        super().__init__(f"{self.source}: {len(self.problems)} problem(s) in the acquisition:\n{lines}")


def header_problems(data, known_keys, format_name, version, prefix=""):
    """The problems of a JSON file's top level that every skintopo format shares: unknown
    fields (typos), and the ``format`` name and ``version`` this reader understands. Each
    message starts with ``prefix``."""
    problems = [f"{prefix}unknown field {key!r}" for key in sorted(set(data) - set(known_keys))]
    if data.get("format") != format_name:
        problems.append(f"{prefix}field 'format' must be {format_name!r}, got {data.get('format')!r}")
    if data.get("version") != version:
        problems.append(f"{prefix}field 'version' must be {version} (this reader's format), got {data.get('version')!r}")
    return problems
