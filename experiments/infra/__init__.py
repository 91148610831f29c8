"""Files and processes of long jobs: atomic writes, manifests, resumable runs, process pools."""
