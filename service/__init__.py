"""bonefit REST service: uploads, a job queue, progress and results over HTTP."""

if __name__ != "bonefit.service":  # one name only: two would make two copies of each class
    raise ImportError(f"import bonefit.service, not {__name__} (the package is installed "
                      "only inside the bonefit namespace)")
