"""Ground-floor helpers every layer may use (layer 0): ``files`` (atomic writes and bounded
reads of regular files, safe text) and ``checks`` (argument checks: ``check_shape``)."""
