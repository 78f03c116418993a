from slearn.cli import main

main()
