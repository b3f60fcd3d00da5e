"""bonefit REST service: uploads, a job queue, progress and results over HTTP."""
