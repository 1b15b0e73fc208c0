"""Exceptions that carry a message meant for the user, not a traceback."""


class SkinTopoError(ValueError):
    """An error caused by the input or the options (a file, a folder, a value given by the
    user), with a message that says what is wrong. A ``ValueError``, so callers that catch
    bad values catch it too.

    The command-line interface prints the message of these errors without a traceback.
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
