"""``--law MODULE:CLASS`` (repeatable): run the controller contract test over a law of your own as well."""


def pytest_addoption(parser):
    parser.addoption("--law", action="append", default=[], metavar="MODULE:CLASS",
                     help="a law outside the package (MODULE:CLASS or FILE.py:CLASS) for test_controller_contract.py")
