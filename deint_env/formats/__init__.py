"""File formats (docs/design.md section 7): `files` (the one atomic writer, whole-file reads), `pulse_csv`
(pulse and label files), `json_files` (priors and scenario files) and `tdc` (Turing Deinterleaving
Challenge HDF5 files; imported on its own, it needs h5py).  The CSV and JSON names are re-exported
here: `from deint_env import formats; formats.read_pulses(...)`."""

from deint_env.formats.files import (PathLike, atomic_path, atomic_write, read_bytes, read_text, write_all,
                                     write_bytes, write_text)
from deint_env.formats.json_files import (format_json, format_priors, loads, read_json, read_priors, true_priors,
                                          write_priors)
from deint_env.formats.pulse_csv import (LABEL_COLUMNS, MAX_LABEL, PULSE_COLUMNS, PulseTable, format_labels,
                                         format_pulses, from_file_labels, read_labels, read_pulse_table, read_pulses,
                                         to_file_labels, write_labels, write_pulses)

__all__ = [
    "LABEL_COLUMNS", "MAX_LABEL", "PULSE_COLUMNS", "PathLike", "PulseTable", "atomic_path", "atomic_write",
    "format_json", "format_labels", "format_priors", "format_pulses", "from_file_labels", "loads", "read_bytes",
    "read_json", "read_labels", "read_priors", "read_pulse_table", "read_pulses", "read_text", "to_file_labels",
    "true_priors", "write_all", "write_bytes", "write_labels", "write_priors", "write_pulses", "write_text",
]
