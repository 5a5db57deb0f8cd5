"""The workflow's logic, owned by the package: what each job reads (``specs``).

The ``.smk`` files declare the rules; they call these functions for anything computed.
"""
