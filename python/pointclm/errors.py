"""The exceptions pointclm raises, one class per kind of problem.

>>> import pointclm
>>> try:
...     pointclm.Network("missing.safetensors")
... except pointclm.errors.WeightsNotFoundError as e:
...     print(type(e).__name__, isinstance(e, FileNotFoundError), isinstance(e, ValueError))
WeightsNotFoundError True True

Hierarchy::

    ValueError
    └── PointclmError                 base; raised itself when a thread pool cannot be built
        ├── InputError                data or an argument the call cannot use
        ├── ConfigError               a Config field unknown or outside its valid range
        ├── NumericalError            arithmetic that cannot be carried out on this input
        ├── WeightsError              a weight file that is not a valid network
        │   └── WeightsNotFoundError  (also PathNotFoundError)
        └── PathNotFoundError         (also FileNotFoundError) a file or folder to read is missing

Every class is a :class:`ValueError`, so ``except ValueError`` written before these classes
existed still catches everything it caught; a missing file or folder is also a
:class:`FileNotFoundError` (``errno``, ``strerror`` and ``filename`` are set where the message
has the ``[Errno 2] ...: 'path'`` form). The message text is the same as before.

Where each error of the Rust core (``pointclm::Error``) goes:

- :class:`InputError`: ``TooFewCorrespondences``, ``TooFewPoints``, ``NonFinite``,
  ``LengthMismatch``, ``InvalidParameter``, ``InvalidMatrix``
- :class:`ConfigError`: ``InvalidConfig``, ``ConfigOutOfRange``
- :class:`NumericalError`: ``EigenNoConvergence``, ``MagnitudeRange``
- :class:`WeightsError`: ``WeightsMalformed``, ``TensorMissing``, ``TensorShape``
- :class:`WeightsNotFoundError`: ``WeightsNotFound`` (the file is missing or unreadable)
- :class:`PointclmError` itself: ``ThreadPool`` (the system would not start the threads)
- :class:`MemoryError`: ``Allocation``; :class:`KeyboardInterrupt`: ``Cancelled`` (Ctrl-C)

The extension module's own argument checks (an array of the wrong shape, an unknown config
field) raise the same classes, and so do the checks the Python layer makes before calling it
(``pointclm.register``'s on its arrays, a :class:`pointclm.Config` field). Failures that are
bugs in pointclm, not in the input, stay :class:`RuntimeError` ("internal error in pointclm
(please report)").

Design decisions
----------------
- **Defined here, in Python, and raised by the Rust extension** (``pyo3::import_exception!``
  in ``rust/pointclm-py/src/errors.rs``), rather than created inside ``pointclm._core``:
  a missing file has to be both a ``ValueError`` (what it was) and a ``FileNotFoundError``,
  and a class with two bases is plain Python but not something ``create_exception!`` can
  make. It also keeps ``__module__`` at ``pointclm.errors``, so errors pickle across
  processes under the name users import.
- **Few classes, named by what the caller fixes** (pydantic-core and tokenizers keep a small
  flat set too): the data, the config, the weight file, or the path. Finer detail (which
  field, which row) is in the message, which is unchanged.
- ``FileNotFoundError`` is the first base of :class:`PathNotFoundError`, so that
  ``PathNotFoundError(errno.ENOENT, "no such file", path)`` fills in ``errno`` and
  ``filename`` like the built-in does.
"""

from __future__ import annotations

__all__ = [
    "ViewpointDisagreementWarning",
    "ConfigError",
    "InputError",
    "NumericalError",
    "PathNotFoundError",
    "PointclmError",
    "WeightsError",
    "WeightsNotFoundError",
]


class PointclmError(ValueError):
    """Base class of pointclm's errors. Raised itself only when the system would not start
    the threads a call asked for."""


class InputError(PointclmError):
    """Data or an argument the call cannot use: too few correspondences or points, a NaN or
    infinite value, arrays whose sizes or shapes do not match, a parameter outside its range,
    or a matrix that is not square, symmetric and finite."""


class ConfigError(PointclmError):
    """A :class:`pointclm.Config` field (or config dict key) that is unknown or outside its
    valid range; the message names the field."""


class NumericalError(PointclmError):
    """Arithmetic that cannot be carried out on this input: an eigendecomposition that did
    not converge, or magnitudes that no common scale brings within float64 range."""


class WeightsError(PointclmError):
    """A weight file (``.safetensors``) or its ``.json`` that is not a valid network: not
    safetensors, invalid JSON, a bad architecture, or a tensor missing or of the wrong
    shape."""


class PathNotFoundError(FileNotFoundError, PointclmError):
    """A file or folder that pointclm was asked to read does not exist: a point cloud, a
    mesh, a data folder or a weight file."""


class WeightsNotFoundError(PathNotFoundError, WeightsError):
    """A weight file, or the ``.json`` of its architecture beside it, that does not exist or
    cannot be read."""


class ViewpointDisagreementWarning(UserWarning):
    """A viewpoint the caller gave is used, though the scan does not look like one view from
    it (:func:`pointclm._core.looks_like_one_view`): it may be merged from several views, in
    another frame, or the position may be wrong. The result records it
    (``PointCloudRegistration.viewpoint_disputed``)."""
